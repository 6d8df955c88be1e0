"""``ff-epos --config PATH [--channel URL] [--enable] [--current A ...] [--hold S]``: configure
EPOS drives over CANopen, optionally enable them and hold a current, print joint states as JSON
lines, then disable.

    ff-epos --config config/bridge_sim_scara2.yaml --channel ws://127.0.0.1:54701/ --enable --hold 5
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from typing import Optional, Sequence

from ff_hwbridge.drive.config import load_config, with_bus
from ff_hwbridge.drive.epos import EposError, EposMaster
from ff_hwbridge.protocol.cia402 import State

__all__ = ["main"]


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Exit code 0 when the drives were disabled cleanly, 1 on a drive error or a latched safe
    state, 2 on a configuration or bus error."""
    ap = argparse.ArgumentParser(prog="ff-epos",
                                 description="Configure EPOS drives over CANopen and print joint states.")
    ap.add_argument("--config", required=True, help="bridge YAML (config/bridge_*.yaml)")
    ap.add_argument("--channel", help="override the bus channel, e.g. ws://127.0.0.1:54701/ (remote)")
    ap.add_argument("--interface", help="override the bus interface (default: remote with --channel ws://...)")
    ap.add_argument("--enable", action="store_true", help="enable operation after configuring")
    ap.add_argument("--current", type=float, nargs="*", default=[], help="A per joint to hold while enabled")
    ap.add_argument("--hold", type=float, default=1.0, help="s to run before disabling")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        cfg = load_config(args.config)
        if args.channel:
            iface = args.interface or ("remote" if args.channel.startswith("ws") else cfg.bus.interface)
            cfg = with_bus(cfg, {"interface": iface, "channel": args.channel, "bitrate": cfg.bus.bitrate})
        master = EposMaster(cfg)
        master.connect()
    except (ValueError, OSError) as exc:
        print(f"ff-epos: {exc}", file=sys.stderr)
        return 2
    try:
        master.configure()
        print(json.dumps({"configured": True, "joints": list(cfg.joint_names)}), flush=True)
        if args.enable:
            master.enable()
            ok = master.wait_for_state(State.OPERATION_ENABLED, 2.0)
            print(json.dumps({"enabled": ok, "reason": master.fault_reason}), flush=True)
            if args.current:
                master.command_currents(args.current)
        t_end = time.monotonic() + args.hold
        while time.monotonic() < t_end:
            time.sleep(0.2)
            print(json.dumps({"joints": [{"q": f.position, "qd": f.velocity, "i": f.current,
                                          "state": f.state.value if f.state else None}
                                         for f in master.feedback()],
                              "safe_state": master.fault_reason}), flush=True)
        master.disable()
        time.sleep(0.05)
        return 0 if not master.latched else 1
    except EposError as exc:
        print(f"ff-epos: {exc}", file=sys.stderr)
        return 1
    finally:
        master.disconnect()


if __name__ == "__main__":
    sys.exit(main())

"""``ff-epos --config PATH [--channel URL] [--fault-reset] [--enable] [--current A ...] [--hold S]``:
configure EPOS drives over CANopen, optionally enable them and hold a current, print joint states
as JSON lines, then disable.

A drive found in Fault after configure is reported with its error code (0x603F) and error
history (0x1003), decoded with maxon's error table; ``--fault-reset`` resets it and goes on,
without it ``ff-epos`` stops (exit 1). Once the safe state latches (a drive fault, a lost
heartbeat, ...) the states stop and the reason and the drive's error code are printed.

    ff-epos --config config/bridge_sim_scara2.yaml --channel ws://127.0.0.1:54701/ --enable --hold 5
"""
from __future__ import annotations

import argparse
import gc
import json
import logging
import sys
import time
from typing import Optional, Sequence

from ff_hwbridge.drive.config import load_config, with_bus
from ff_hwbridge.drive.epos import EposError, EposMaster
from ff_hwbridge.drive.realtime import (SWITCH_INTERVAL, ProcessTiming, RealtimeConfig, freeze_heap,
                                        hold_full_collections, restore_process, setup_process)
from ff_hwbridge.protocol.cia402 import State

__all__ = ["main"]

FAULT_STATES = (State.FAULT, State.FAULT_REACTION_ACTIVE)


def _faulted(master: EposMaster) -> list[str]:
    """The joints whose drive reports Fault (waits up to ``state_timeout`` s for a statusword
    from every drive)."""
    end = time.monotonic() + master.config.state_timeout
    while time.monotonic() < end and any(s is None for s in master.states()):
        time.sleep(0.01)
    return [n for n, s in zip(master.joint_names, master.states()) if s in FAULT_STATES]


def _report_faults(master: EposMaster, joints: Sequence[str]) -> None:
    for name in joints:
        print(json.dumps({"fault": name, "error": master.read_error_history(name)}), flush=True)


def _fresh_state(master: EposMaster) -> list[Optional[str]]:
    """Per joint the drive's state, None when its feedback is older than ``feedback_timeout``
    (a drive gone PRE-OPERATIONAL sends none: its last state is no longer true)."""
    now = master.clock()
    limit = master.config.feedback_timeout
    return [f.state.value if f.state is not None and now - f.stamp <= limit else None
            for f in master.feedback()]


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Exit code 0 when the drives were disabled cleanly, 1 on a drive error, a drive in Fault at
    start (without ``--fault-reset``) or a latched safe state, 2 on a configuration or bus error."""
    ap = argparse.ArgumentParser(prog="ff-epos",
                                 description="Configure EPOS drives over CANopen and print joint states.")
    ap.add_argument("--config", required=True, help="bridge YAML (config/bridge_*.yaml)")
    ap.add_argument("--channel", help="override the bus channel, e.g. ws://127.0.0.1:54701/ (remote)")
    ap.add_argument("--interface", help="override the bus interface (default: remote with --channel ws://...)")
    ap.add_argument("--fault-reset", action="store_true",
                    help="reset drives found in Fault (after printing their error code) and go on")
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
    saved: Optional[ProcessTiming] = None
    thresholds: Optional[tuple[int, int, int]] = None
    try:
        # from configure on the watchdogs judge SYNC and heartbeats, and once enabled the bus
        # receiver sends the setpoint RPDO every SYNC cycle (a cycle without it faults the drive,
        # EMCY 0x8250), all on this process's GIL: one full garbage collection now, before
        # anything is timed, what survives frozen out of later scans, no automatic full one
        freeze_heap()
        thresholds = hold_full_collections()
        master.configure()
        if cfg.rt_priority > 1:
            # the bus receiver (SCHED_FIFO since configure) writes every SYNC cycle's RPDO: no
            # thread here that may hold the GIL runs at normal priority (preempted, it would
            # hold the receiver off for longer than a cycle), and the GIL changes hands fast
            saved = ProcessTiming.now()
            setup_process(RealtimeConfig(priority=cfg.rt_priority - 1, switch_interval=SWITCH_INTERVAL),
                          "ff-epos")
        print(json.dumps({"configured": True, "joints": list(cfg.joint_names)}), flush=True)
        faulted = _faulted(master)
        if faulted:
            _report_faults(master, faulted)
            if not args.fault_reset:
                print(f"ff-epos: drive(s) in Fault: {', '.join(faulted)} (error code above); "
                      "'ff-epos --fault-reset ...' resets them", file=sys.stderr)
                return 1
            master.fault_reset(reenable=False)
            ok = master.wait_for_state(State.SWITCH_ON_DISABLED, cfg.state_timeout)
            print(json.dumps({"fault_reset": ok, "states": _fresh_state(master)}), flush=True)
            if not ok:
                return 1
        if args.enable:
            master.enable()
            ok = master.wait_for_state(State.OPERATION_ENABLED, 2.0)
            print(json.dumps({"enabled": ok, "reason": master.fault_reason}), flush=True)
            if args.current:
                master.command_currents(args.current)
        t_end = time.monotonic() + args.hold
        while time.monotonic() < t_end:
            time.sleep(0.2)
            if master.latched:
                _report_faults(master, [n for n, s in zip(master.joint_names, master.states())
                                        if s in FAULT_STATES])
                print(json.dumps({"safe_state": master.fault_reason}), flush=True)
                break
            print(json.dumps({"joints": [{"q": f.position, "qd": f.velocity, "i": f.current, "state": s}
                                         for f, s in zip(master.feedback(), _fresh_state(master))],
                              "safe_state": master.fault_reason}), flush=True)
        master.disable()
        time.sleep(0.05)
        return 0 if not master.latched else 1
    except EposError as exc:
        print(f"ff-epos: {exc}", file=sys.stderr)
        return 1
    finally:
        master.disconnect()
        if thresholds is not None:      # main() called in a longer-lived process (tests)
            gc.unfreeze()
            gc.set_threshold(*thresholds)
        if saved is not None:           # main() called in a longer-lived process (tests)
            restore_process(saved)


if __name__ == "__main__":
    sys.exit(main())

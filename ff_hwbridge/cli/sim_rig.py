"""``ff-sim-rig``: the simulated drive + arm on the loopback CAN hub, without ROS.

    ff-sim-rig --host-hub 54701 --model arm1dof --node-ids 1
    ff-sim-rig --bus-url ws://127.0.0.1:54701/ --record setpoints.json

Prints ``sim rig ready`` once the drives have booted, reads commands from stdin (one a line,
``ff_hwbridge.sim.rig.run_command``), and on SIGINT/SIGTERM (or the command ``quit``) writes the
setpoint arrival log as JSON to ``--record``.
"""
from __future__ import annotations

import argparse
import signal
import sys
import threading
from typing import Optional, Sequence

from ff_hwbridge.sim.can_hub import CanHub, start_hub
from ff_hwbridge.sim.drive import SimConfigError
from ff_hwbridge.sim.rig import SWITCH_INTERVAL, RigConfig, SimRig, run_command, write_record
from ff_planner.model.params import MODELS, ParameterError, default_params

__all__ = ["main"]


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Run the rig until SIGINT/SIGTERM or ``quit``; exit code 2 on a setting that cannot be used."""
    ap = argparse.ArgumentParser(prog="ff-sim-rig",
                                 description="Simulated EPOS drives + arm on one CAN bus (no ROS).")
    where = ap.add_mutually_exclusive_group(required=True)
    where.add_argument("--bus-url", help="join a CAN hub: ws://127.0.0.1:PORT/")
    where.add_argument("--host-hub", type=int, metavar="PORT", help="host the hub on 127.0.0.1:PORT")
    ap.add_argument("--model", default="arm1dof", choices=tuple(MODELS))
    ap.add_argument("--node-ids", default="1", help="comma-separated, one per joint")
    ap.add_argument("--family", default="epos4", choices=("epos4", "epos2"))
    ap.add_argument("--q0", default="0", help="comma-separated initial joint angles (rad)")
    ap.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                    help="true model parameter (e.g. pc=0.25), repeatable")
    ap.add_argument("--step", type=float, default=1e-4, help="s, physics sub-step")
    ap.add_argument("--record", help="write the setpoint arrival log (JSON) here on exit")
    ap.add_argument("--switch-interval", type=float, default=SWITCH_INTERVAL, metavar="S",
                    help="python thread switch interval (s, python's default 0.005); smaller = "
                         "shorter waits of the CAN receive thread behind other threads")
    a = ap.parse_args(argv)
    if a.switch_interval and a.switch_interval > 0:
        sys.setswitchinterval(a.switch_interval)
    hub: Optional[CanHub] = None
    try:
        params = default_params(a.model).replace(**dict(kv.split("=", 1) for kv in a.param))
        if a.host_hub is not None:
            hub = start_hub(a.host_hub)
            bus = hub.local_bus_config()      # same process: join the hub's channel directly
        else:
            bus = {"interface": "remote", "channel": a.bus_url}
        cfg = RigConfig(model=a.model, node_ids=tuple(int(x, 0) for x in a.node_ids.split(",")),
                        family=a.family, bus=bus,
                        true_params=params, q0=tuple(float(x) for x in a.q0.split(",")),
                        step=a.step)
        rig = SimRig(cfg)
    except (ParameterError, SimConfigError, ValueError) as exc:
        print(f"ff-sim-rig: {exc}", file=sys.stderr)
        if hub is not None:
            hub.close()
        return 2
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())

    def read_stdin() -> None:
        for line in sys.stdin:          # EOF (stdin /dev/null) just ends the reader
            if line.strip() == "quit":
                stop.set()
                return
            print(run_command(rig, line), flush=True)

    rig.boot()
    if hub is not None:
        print(f"CAN hub on {hub.url}", flush=True)
    print("sim rig ready", flush=True)
    if not sys.stdin.isatty():
        threading.Thread(target=read_stdin, daemon=True).start()
    while not stop.wait(0.1):
        pass
    if a.record:
        write_record(rig, a.record)
    rig.close()
    if hub is not None:
        hub.close()
    print("sim rig stopped", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""``ff-sim-rig``: the simulated drive + arm on the loopback CAN hub, without ROS.

    ff-sim-rig --host-hub 54701 --model arm1dof --node-ids 1
    ff-sim-rig --bus-url ws://127.0.0.1:54701/ --record setpoints.json

Prints ``sim rig ready`` once the drives have booted, reads commands from stdin (one a line,
``ff_hwbridge.sim.rig.run_command``), and on SIGINT/SIGTERM (or the command ``quit``) writes the
setpoint arrival log as JSON to ``--record``.

``--boot-delay S``: the drives are powered S s after ``sim rig ready`` (they answer nothing before,
as a drive that is still off). ``--nominal-current A``: the motor data the drives are set up with.
On a hub it joined (``--bus-url``) the rig treats a lost hub as bus off (the drives fault with
0x81FD and drive no current), reconnects every 0.5 s and puts the drives back on the bus
(PRE-OPERATIONAL, EMCY 0x81FD), and exits with code 3 when the hub is not back within
``--reconnect-timeout`` s; each step is a line on stderr.

``--sync-period S`` (with ``--host-hub``): the hosted hub produces SYNC every S s (its timer
under SCHED_FIFO ``--sync-rt-priority``, and without ``--rt-priority`` every other thread one
below it, as ``ff-can-hub`` does); the simulated drives then sit on
the hub's channel itself, with no websocket between them and the bus. The hub's SYNC and
transmit-schedule statistics go into the ``--record`` file (``hub``).

``--rt-priority P`` (1..99) puts every thread of the rig (python-can's receive thread, the bus
watch, the plant's clock, the drives' timers) under SCHED_FIFO P once it is up: a loaded machine
holds normal-priority processes off their CPU for 0.1-1.4 s, and the drives must react to a lost
bus or a silent master within their own timeouts (a warning, and normal priority, when Linux
does not permit it).
"""
from __future__ import annotations

import argparse
import signal
import sys
import threading
from typing import Optional, Sequence

from ff_hwbridge.drive.realtime import freeze_heap
from ff_hwbridge.drive.scheduler import fifo_process
from ff_hwbridge.sim.can_hub import CanHub, start_hub
from ff_hwbridge.sim.drive import SimConfigError
from ff_hwbridge.sim.rig import SWITCH_INTERVAL, RigConfig, SimRig, run_command, write_record
from ff_hwbridge.sim.time_keeper import keeper_stats
from ff_planner.model.params import MODELS, ParameterError, default_params

__all__ = ["main"]


def hub_stats(hub: CanHub) -> dict:
    """The hosted hub's SYNC statistics (None without SYNC) and its transmit schedule's."""
    return {"sync": hub.sync.stats().as_dict() if hub.sync is not None else None,
            "time_keeper": keeper_stats(hub.channel)}


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
    ap.add_argument("--nominal-current", type=float, default=None, metavar="A",
                    help="nominal current the drives are set up with (0x3001:01; default 3 A)")
    ap.add_argument("--boot-delay", type=float, default=0.0, metavar="S",
                    help="power the drives this many seconds after start (a drive powered late)")
    ap.add_argument("--reconnect-timeout", type=float, default=30.0, metavar="S",
                    help="with --bus-url: exit (code 3) when the hub is gone this long")
    ap.add_argument("--record", help="write the setpoint arrival log (JSON) here on exit")
    ap.add_argument("--switch-interval", type=float, default=SWITCH_INTERVAL, metavar="S",
                    help="python thread switch interval (s, python's default 0.005); smaller = "
                         "shorter waits of the CAN receive thread behind other threads")
    ap.add_argument("--sync-period", type=float, default=0.0, metavar="S",
                    help="with --host-hub: the hub produces SYNC every S s (0 = none)")
    ap.add_argument("--sync-rt-priority", type=int, default=50, metavar="P",
                    help="SCHED_FIFO priority of the hosted hub's SYNC timer (0 = normal)")
    ap.add_argument("--rt-priority", type=int, default=0, metavar="P",
                    help="SCHED_FIFO priority 1..99 for every thread of the rig (0 = normal "
                         "priority)")
    a = ap.parse_args(argv)
    if not (0 <= a.rt_priority <= 99 and 0 <= a.sync_rt_priority <= 99):
        print(f"ff-sim-rig: --rt-priority and --sync-rt-priority must be 0..99, got "
              f"{a.rt_priority} / {a.sync_rt_priority}", file=sys.stderr)
        return 2
    if a.sync_period and (a.host_hub is None or not 0.0001 <= a.sync_period <= 1.0):
        print(f"ff-sim-rig: --sync-period needs --host-hub and 0.0001..1 s, got {a.sync_period}",
              file=sys.stderr)
        return 2
    if not (a.boot_delay >= 0.0 and a.reconnect_timeout > 0.0):
        print(f"ff-sim-rig: --boot-delay must be >= 0 s and --reconnect-timeout > 0 s, got "
              f"{a.boot_delay} / {a.reconnect_timeout}", file=sys.stderr)
        return 2
    if a.switch_interval and a.switch_interval > 0:
        sys.setswitchinterval(a.switch_interval)
    hub: Optional[CanHub] = None
    try:
        params = default_params(a.model).replace(**dict(kv.split("=", 1) for kv in a.param))
        if a.host_hub is not None:
            hub = start_hub(a.host_hub, sync_period=a.sync_period,
                            sync_rt_priority=a.sync_rt_priority)
            bus = hub.local_bus_config()      # same process: join the hub's channel directly
        else:
            bus = {"interface": "remote", "channel": a.bus_url}
        cfg = RigConfig(model=a.model, node_ids=tuple(int(x, 0) for x in a.node_ids.split(",")),
                        family=a.family, bus=bus,
                        true_params=params, q0=tuple(float(x) for x in a.q0.split(",")),
                        step=a.step,
                        **({"nominal_current": a.nominal_current} if a.nominal_current is not None else {}))
        rig = SimRig(cfg)
    except (ParameterError, SimConfigError, ValueError) as exc:
        print(f"ff-sim-rig: {exc}", file=sys.stderr)
        if hub is not None:
            hub.close()
        return 2
    stop = threading.Event()
    gave_up = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())

    def say(text: str) -> None:
        # one write per line: python-can's receive thread may print its traceback meanwhile,
        # and print() writes the text and its newline apart
        sys.stderr.write(f"ff-sim-rig: {text}\n")
        sys.stderr.flush()

    if hub is None:
        def give_up() -> None:
            gave_up.set()
            stop.set()

        rig.watch_bus(say, give_up, a.reconnect_timeout)

    def read_stdin() -> None:
        for line in sys.stdin:          # EOF (stdin /dev/null) just ends the reader
            if line.strip() == "quit":
                stop.set()
                return
            print(run_command(rig, line), flush=True)

    if hub is not None:
        print(f"CAN hub on {hub.url}", flush=True)
    if a.boot_delay > 0:
        print(f"ff-sim-rig: drives powered in {a.boot_delay:g} s", file=sys.stderr, flush=True)
        for d in rig.drives:
            d.power_off()
        threading.Timer(a.boot_delay, rig.boot).start()
    else:
        rig.boot()
    freeze_heap()       # a full collection would hold the drives' bus thread off the GIL
    rt = a.rt_priority
    if rt == 0 and hub is not None and a.sync_period and a.sync_rt_priority > 1:
        rt = a.sync_rt_priority - 1         # as ff-can-hub: every thread one below the SYNC timer
    if rt > 0:
        fifo_process(rt, "ff-sim-rig")      # threads started later inherit it
    print("sim rig ready", flush=True)
    if not sys.stdin.isatty():
        threading.Thread(target=read_stdin, daemon=True).start()
    while not stop.wait(0.1):
        pass
    if a.record:
        write_record(rig, a.record, None if hub is None else hub_stats(hub))
    rig.close()
    if hub is not None:
        hub.close()
    print("sim rig stopped", flush=True)
    return 3 if gave_up.is_set() else 0


if __name__ == "__main__":
    sys.exit(main())

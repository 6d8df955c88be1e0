"""``ff-can-hub [--port P] [--host 127.0.0.1] [--sync-period S]``: serve the loopback CAN hub
until SIGINT/SIGTERM, optionally producing SYNC itself.

Prints ``CAN hub on ws://127.0.0.1:PORT/`` once serving and ``CAN hub stopped`` on the way out.
With ``--sync-period`` (s, e.g. 0.001) the hub produces SYNC (COB-ID 0x80) from a timer thread
(SCHED_FIFO ``--sync-rt-priority`` when permitted; the hub's forwarding threads one below it,
so that none of them is preempted while holding the GIL the timer needs) and prints its jitter as one JSON line
``{"sync": {...}}`` (count, skipped, jitter_p50_us / p99 / max, period_us, realtime, the timing
model and the measured send lateness) every ``--sync-report`` s (0 = never), on SIGUSR1, and at
exit. ``--sync-stamp deadline`` (default): the SYNC's bus instant is the timer's deadline plus a
modelled jitter up to ``--sync-jitter-model-us``; ``send``: the instant the thread sent it.

``--rt-priority P`` (1..99) puts every thread of the hub under SCHED_FIFO P (with
``--sync-period``, the forwarding threads; the SYNC timer keeps ``--sync-rt-priority``). A hub
that stands for the bus in a timed test then forwards, and dies when killed, without waiting for
a CPU that ordinary processes hold (a warning, and normal priority, when Linux does not permit
it).
"""
from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from typing import Optional, Sequence

from ff_hwbridge.drive.bus import LOOPBACK, CanConfigError
from ff_hwbridge.drive.realtime import fifo_process, freeze_heap
from ff_hwbridge.sim.time_keeper import keeper_stats
from ff_hwbridge.sim.can_hub import CanHub, start_hub
from ff_hwbridge.sim.sync import STAMPS

__all__ = ["main"]

#: s, the interpreter's thread switch interval in the hub (default 5 ms): the SYNC timer thread
#: gets the GIL back from the hub's forwarding threads within this
SWITCH_INTERVAL = 0.0001


def _report(hub: CanHub) -> None:
    keeper = keeper_stats(hub.channel)
    if hub.sync is not None or keeper is not None:
        print(json.dumps({"sync": hub.sync.stats().as_dict() if hub.sync is not None else None,
                          "time_keeper": keeper}), flush=True)


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Serve the hub until SIGINT/SIGTERM; exit code 2 on a setting that cannot be used."""
    ap = argparse.ArgumentParser(prog="ff-can-hub",
                                 description="One CAN bus shared by processes on this machine, "
                                             "on loopback only.")
    ap.add_argument("--port", type=int, default=54701, help="TCP port on 127.0.0.1 (0 = any free)")
    ap.add_argument("--host", default=LOOPBACK, help="loopback address to bind (default 127.0.0.1)")
    ap.add_argument("--sync-period", type=float, default=0.0,
                    help="s, produce SYNC (0x80) at this period (0 = no SYNC from the hub)")
    ap.add_argument("--sync-rt-priority", type=int, default=50,
                    help="SCHED_FIFO priority of the SYNC timer thread (0 = normal; falls back "
                         "with a warning when not permitted)")
    ap.add_argument("--sync-stamp", choices=STAMPS, default="deadline",
                    help="SYNC timing model: 'deadline' = bus instant at the timer's deadline "
                         "(+ modelled jitter; a kernel/hardware timer), 'send' = when the thread "
                         "sent it (default deadline)")
    ap.add_argument("--sync-jitter-model-us", type=float, default=0.0,
                    help="µs, modelled SYNC jitter of the deadline model: uniform in [0, this] "
                         "(default 0)")
    ap.add_argument("--sync-report", type=float, default=0.0,
                    help="s, print the SYNC jitter as a JSON line this often (0 = at exit and "
                         "on SIGUSR1 only)")
    ap.add_argument("--rt-priority", type=int, default=0,
                    help="SCHED_FIFO priority of every thread of the hub (0 = normal, the default; "
                         "with --sync-period its forwarding threads default to one below the "
                         "SYNC timer)")
    args = ap.parse_args(argv)
    if args.sync_period and not 0.0001 <= args.sync_period <= 1.0:
        print(f"ff-can-hub: --sync-period must be 0.0001..1 s, got {args.sync_period}", file=sys.stderr)
        return 2
    if not (0.0 <= args.sync_jitter_model_us <= 100_000.0 * (args.sync_period or 1.0)):
        print(f"ff-can-hub: --sync-jitter-model-us must be 0..10 % of the period, got "
              f"{args.sync_jitter_model_us}", file=sys.stderr)
        return 2
    if not (0 <= args.sync_rt_priority <= 99 and 0 <= args.rt_priority <= 99):
        print(f"ff-can-hub: --sync-rt-priority and --rt-priority must be 0..99, got "
              f"{args.sync_rt_priority} / {args.rt_priority}", file=sys.stderr)
        return 2
    rt = args.rt_priority
    if args.sync_period:
        sys.setswitchinterval(SWITCH_INTERVAL)
        if rt == 0 and args.sync_rt_priority > 1:
            # the forwarding threads one below the SYNC timer: no GIL holder is preempted by
            # ordinary processes while the timer waits for the GIL
            rt = args.sync_rt_priority - 1
    if rt > 0:
        fifo_process(rt, "ff-can-hub")      # threads started later inherit it (a warning when
        #                                     Linux does not permit it)
    try:
        hub = start_hub(args.port, args.host, sync_period=args.sync_period,
                        sync_rt_priority=args.sync_rt_priority, sync_stamp=args.sync_stamp,
                        sync_jitter_model=args.sync_jitter_model_us * 1e-6)
    except CanConfigError as exc:
        print(f"ff-can-hub: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    report = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    signal.signal(signal.SIGUSR1, lambda *_: report.set())
    freeze_heap()       # a full collection would hold the SYNC timer thread off the GIL
    print(f"CAN hub on {hub.url}" + (f", SYNC every {args.sync_period * 1000.0:g} ms"
                                      if args.sync_period else ""), flush=True)
    waited = 0.0
    while not stop.wait(0.2):
        waited += 0.2
        if report.is_set() or (args.sync_report and waited >= args.sync_report):
            report.clear()
            waited = 0.0
            _report(hub)
    _report(hub)
    hub.close()
    print("CAN hub stopped", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

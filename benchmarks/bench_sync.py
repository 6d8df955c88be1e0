"""Benchmark: synchronous setpoints on the simulated stack: a setpoint every SYNC cycle, latched by
the simulated EPOS at the SYNC's bus instant. Prints one JSON object.

Processes: the CAN hub producing SYNC (``ff-can-hub --sync-period``, its timer thread under
SCHED_FIFO when permitted), the simulated EPOS4 + arm (``ff-sim-rig --bus-url``, recording each
latched setpoint with the SYNC instant it took effect at), and this one: the bridge's
``EposMaster`` (``sync_producer: external``, RPDO transmission type 1) and ``SetpointPlayer``
(default priorities unless ``--rt-priority``), stamps on the SYNC grid one period apart; with
``--player-process`` the player runs in its own process (``ProcessPlayer``: its own bus
connection, SYNC watch, guard, units and RPDO send) and this process only feeds it.

Figures:
- ``switch_error_us``: latched SYNC instant at the simulated drive − planned time (stamp), p50 /
  p99 / max (goal p99 <= 20 µs quiet, <= 50 µs with ``--load 2``);
- ``sync_jitter_us``: the hub's SYNC send instant − its nominal grid instant (the hub's report);
  ``sync_interval_jitter_us``: |interval − period| of the SYNCs the master received;
- ``missed_cycles``: setpoints that took effect after their own SYNC (player's count), and
  ``late_at_drive``: those the drive latched at another SYNC than the one at their stamp;
- ``lost``: setpoints sent minus setpoints the drive latched (goal 0 and 0);
- ``send_after_sync_us``: how long after the SYNC before it each RPDO was sent (the margin used).

    .venv/bin/python benchmarks/bench_sync.py --duration 60            # quiet
    .venv/bin/python benchmarks/bench_sync.py --duration 60 --load 2   # two busy processes
    .venv/bin/python benchmarks/bench_sync.py --duration 60 --load 2 --player-process
    .venv/bin/python benchmarks/bench_sync.py --duration 60 --player-process --lead 0.02

``--lead S`` (with ``--player-process``): the bridge's ``setpoint_lead``: each setpoint is handed
to the hub's transmit schedule up to S before its cycle and goes on the bus mid-cycle before its
SYNC (``ff_hwbridge.sim.time_keeper``); ``time_keeper`` reports what the hub's schedule sent,
cancelled and how late its thread was.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np
from _common import (busy_processes, enable_drive, feed_stream, match_stream, percentiles, release_rig, stop_drive,
                     stop_processes)

from ff_hwbridge.drive.epos import EposMaster
from ff_hwbridge.drive.realtime import freeze_heap, hold_full_collections
from ff_hwbridge.drive.player import PlayerConfig, SetpointPlayer
from ff_hwbridge.drive.player_process import ProcessPlayer
from ff_hwbridge.sim.rig_process import RigProcess, free_port, rig_master_config
from ff_msgs_py.configs import node_parameters


#: ns: setpoints are submitted this long before their stamp: the simulated stack's executor
#: lead_time (config/executor_sim.yaml)
FEED_AHEAD_NS = int(round(float(node_parameters("executor_sim.yaml", "ff_executor")["lead_time"]) * 1e9))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0, help="s of streaming")
    ap.add_argument("--sync-period", type=float, default=0.001, help="s (one setpoint per SYNC)")
    ap.add_argument("--sync-stamp", choices=("deadline", "send"), default="deadline",
                    help="the hub's SYNC timing model (ff-can-hub --sync-stamp)")
    ap.add_argument("--load", type=int, default=0, help="busy processes to run beside it")
    ap.add_argument("--hub-rt-priority", type=int, default=50,
                    help="SCHED_FIFO priority of the hub's SYNC timer (ff-can-hub's default)")
    ap.add_argument("--rt-priority", type=int, default=-1,
                    help="SCHED_FIFO priority of the player's thread (0 = normal priority; -1 = "
                         "the bridge's default: 50 with SYNC)")
    ap.add_argument("--missed-tolerance", type=int, default=1,
                    help="missed_cycle_tolerance of the master (beyond it: safe state)")
    ap.add_argument("--process-rt", type=int, default=0,
                    help="SCHED_FIFO for this whole process (every thread, as 'chrt -f N' would), "
                         "to measure what a master process with no normal-priority thread gains")
    ap.add_argument("--nice", type=int, default=-10,
                    help="nice value of this process (the bridge's stand-in: the simulated stack "
                         "runs its bridge at nice -10), where permitted; threads started later "
                         "inherit it")
    ap.add_argument("--sim-rt-priority", type=int, default=0,
                    help="SCHED_FIFO for the simulated drive's process (chrt -f N; 0 = normal; "
                         "with --hub rig 0 = as ff-can-hub: one below the SYNC timer)")
    ap.add_argument("--player-process", action="store_true",
                    help="the player in its own process (player_process: true)")
    ap.add_argument("--hub", choices=("process", "rig"), default="process",
                    help="the CAN hub and its SYNC in a process of their own (ff-can-hub), or "
                         "hosted by the simulated rig (ff-sim-rig --host-hub --sync-period: the "
                         "simulated drive on the hub's channel, no websocket hop for it)")
    ap.add_argument("--feedback-every", type=int, default=1,
                    help="SYNCs per feedback TPDO (the bridge's feedback_every; e.g. 10 at 1 kHz)")
    ap.add_argument("--lead", type=float, default=0.0,
                    help="s: setpoint_lead, setpoints handed to the hub's transmit schedule this "
                         "early (needs --player-process; 0 = off)")
    a = ap.parse_args()
    if a.lead > 0 and not a.player_process:
        ap.error("--lead needs --player-process")

    load = busy_processes(a.load)
    port = free_port()
    url = f"ws://127.0.0.1:{port}/"
    record = os.path.join(tempfile.mkdtemp(prefix="ff-bench-sync-"), "sim.json")
    load_before = os.getloadavg()
    hub = None
    if a.hub == "process":
        hub = subprocess.Popen([sys.executable, "-u", "-m", "ff_hwbridge.cli.can_hub", "--port",
                                str(port), "--sync-period", str(a.sync_period),
                                "--sync-rt-priority", str(a.hub_rt_priority), "--sync-stamp",
                                a.sync_stamp],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert hub.stdout is not None
        hub.stdout.readline()
        sim = RigProcess(["--record", record], port=port, host_hub=False, bus_url=url,
                         prefix=["chrt", "-f", str(a.sim_rt_priority)] if a.sim_rt_priority > 0 else ())
    else:       # the rig hosts the hub and its SYNC: the drive on the channel itself
        sim = RigProcess(["--record", record, "--sync-period", str(a.sync_period),
                          "--sync-rt-priority", str(a.hub_rt_priority),
                          "--rt-priority", str(a.sim_rt_priority)], port=port, host_hub=True)
    master = None
    hub_sync: dict = {}
    hub_keeper = None
    submitted = 0
    try:
        cfg = rig_master_config(url, "epos4", 10.0, sync_period=a.sync_period,
                                sync_producer="external", heartbeat_producer_ms=10,
                                # a timing benchmark, not a safety test
                                heartbeat_timeout=1.0, feedback_timeout=1.0, sync_timeout=1.0,
                                master_heartbeat_timeout_ms=5000, rpdo_timeout_ms=5000,
                                setpoint_timeout=1.0, missed_cycle_tolerance=a.missed_tolerance,
                                player_process=bool(a.player_process), setpoint_lead=a.lead,
                                feedback_every=a.feedback_every)
        if a.process_rt > 0:       # after the children started (they keep normal priority)
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(a.process_rt))
        nice = None
        if a.nice:                 # before the master's and the player's threads: they inherit it
            try:
                nice = os.nice(a.nice - os.nice(0))
            except PermissionError:
                print(f"nice {a.nice} not permitted; running at nice {os.nice(0)}", file=sys.stderr)
        master = EposMaster(cfg)
        if not enable_drive(master):
            raise SystemExit(f"drive not enabled: {master.fault_reason}")
        kind = ProcessPlayer if a.player_process else SetpointPlayer
        pcfg = PlayerConfig.from_bridge(cfg) if a.rt_priority < 0 else PlayerConfig(rt_priority=a.rt_priority)
        player = kind(master, pcfg).start()
        freeze_heap()           # as the bridge node does at activation (gc_pauses)
        hold_full_collections()
        while player.sync_grid() is None:
            if master.latched:
                raise SystemExit(f"safe state before the stream: {master.fault_reason}")
            time.sleep(0.01)
        time.sleep(0.2)
        nominal, period = player.sync_grid()   # type: ignore[misc]
        n = int(a.duration / a.sync_period)
        pattern = [(((k * 37) % 61) - 30) * 0.01 for k in range(n)]   # |I| <= 0.3 A
        t0 = nominal + (int(0.5e9) // period) * period                  # on the SYNC grid
        stamps = [t0 + k * period for k in range(n)]
        player.reset_stats()
        # safe state: feeding stops, and the figures cover what ran until then
        # fed up to FEED_AHEAD_NS ahead, as the executor publishes (lead_time) and the bridge forwards
        applied: dict = {}

        def drain() -> None:       # the player keeps the latest 10 000 reports only
            applied.update((r.stamp_ns, r) for r in player.take_applied())

        submitted = feed_stream(player, stamps, pattern, mark_last=True, ahead_ns=FEED_AHEAD_NS,
                                on_poll=drain)
        time.sleep(2.0)        # the simulated drive's process may lag the stream on a busy machine
        diag = player.diagnostics()
        drain()
        latched = stop_drive(player, master)
    finally:
        release_rig(master, sim)
        if hub is not None:
            hub.send_signal(signal.SIGTERM)
            out, _ = hub.communicate(timeout=10)
            for line in out.splitlines():
                if line.startswith("{"):
                    hub_sync = json.loads(line).get("sync", {})
                    hub_keeper = json.loads(line).get("time_keeper")
        stop_processes(load)

    with open(record) as fh:
        rec = json.load(fh)
    if a.hub == "rig":
        hub_sync = (rec.get("hub") or {}).get("sync") or {}
        hub_keeper = (rec.get("hub") or {}).get("time_keeper")
    latched_log = rec["setpoints"]["1"]             # [mono_ns, wall_ns (SYNC instant), raw, A]
    units = master.units[0]
    want = [units.amps_to_setpoint(x, limit=10.0) for x in pattern]
    _, found, _ = match_stream([r[2] for r in latched_log], want, submitted)
    # only setpoints the player reported applied (after a safe state the rest were dropped)
    matched = [(k, latched_log[i]) for k, i in found if stamps[k] in applied]
    err_us = np.array([(r[1] - stamps[k]) / 1000.0 for k, r in matched])
    late_at_drive = int(np.sum(err_us > 0.5 * a.sync_period * 1e6)) if err_us.size else 0
    lead = np.array([(applied[s].sent_ns - applied[s].rpdo_sent_ns) / 1000.0 for s in stamps
                     if s in applied])
    result = {"benchmark": "bench_sync", "host": platform.node(), "cpus": os.cpu_count(),
              "duration_s": a.duration, "sync_period_s": a.sync_period, "busy_processes": a.load,
              "transport": "python-can-remote hub on 127.0.0.1, SYNC from the hub's timer thread",
              "hub": a.hub, "link_stats": rec.get("link_stats"),
              "player_process": bool(a.player_process), "sim_rt_priority": a.sim_rt_priority,
              "player_rt_priority": pcfg.rt_priority, "hub_rt_priority": a.hub_rt_priority,
              "process_rt_priority": a.process_rt, "nice": nice, "setpoint_lead_s": a.lead,
              "feed_ahead_s": FEED_AHEAD_NS / 1e9,
              "feedback_every": a.feedback_every,
              "time_keeper": hub_keeper,
              "loadavg_1min_before_after": [load_before[0], os.getloadavg()[0]],
              "setpoints_planned": n, "setpoints_sent": submitted,
              "setpoints_applied": len(applied), "setpoints_latched": len(matched),
              "lost": len(applied) - len(matched),
              "missed_cycles": diag.get("missed_setpoints"),
              "missed_cycles_max": diag.get("missed_cycles_max"),
              "late_at_drive": late_at_drive,
              "switch_error_us": percentiles(err_us),
              "sync_jitter_us": {k: hub_sync.get(k) for k in ("jitter_p50_us", "jitter_p99_us",
                                                               "jitter_max_us", "count", "skipped",
                                                               "realtime")},
              "sync_interval_jitter_us": {"p99": diag.get("sync_jitter_p99_us"),
                                          "max": diag.get("sync_jitter_max_us"),
                                          "missing": diag.get("sync_missing")},
              "rpdo_before_its_sync_us": percentiles(lead),
              "safe_state": latched}
    p99 = result["switch_error_us"].get("p99", float("inf"))   # type: ignore[union-attr]
    result["goal_p99_us"] = 50.0 if a.load else 20.0
    result["goal_met"] = bool(p99 <= result["goal_p99_us"] and result["lost"] == 0
                              and result["missed_cycles"] == 0)
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark: sustained 1 kHz current-setpoint stream, bridge master -> simulated EPOS, across
processes over the loopback CAN hub. Prints one JSON object.

Process A (child): ``python -m ff_hwbridge.cli.sim_rig --host-hub PORT`` (hub + emulated EPOS4 +
arm), recording every setpoint's arrival (wall clock ns). Process B (this one): the bridge's
``EposMaster`` (SDO/PDO set-up, SYNC at 1 kHz, heartbeat and TPDO monitoring) and its
``SetpointPlayer`` (the bridge node's path: guard, units, RPDO at each stamp, 1 ms apart).

Figures:
- ``lost``: setpoints sent by the master minus setpoints that arrived at the drive (goal 0);
- ``switch_error_us``: applied (arrival at the simulated drive) − stamp, p50 / p99 / max / min;
  ``jitter_us``: the same minus its median (a common delay is harmless to a profile; the spread
  between switches moves the final position) — goal p99 <= 250 µs;
- ``sent_error_us``: the player's own send time − stamp (the master side alone);
- ``transport_us``: arrival at the drive − the master's send time (hub + simulated drive);
- ``feedback``: TPDO statusword/position frames the master received vs SYNCs sent.

``--timing on_receipt`` (default): setpoint RPDOs of transmission type 255 sent at each stamp,
the event-driven path; the synchronous path (latched at SYNC) is ``benchmarks/bench_sync.py``.

Master-side options: ``--rt-priority`` (SCHED_FIFO of the player's thread), ``--switch-interval``
(this process's thread switch interval), ``--spin-margin``, ``--prepare on|off`` (clamp + unit
conversion before the stamp, as the bridge node does, or all at the stamp).

    .venv/bin/python benchmarks/bench_can_stream.py --duration 60 --rate 1000
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time

import numpy as np
from _common import enable_drive, feed_stream, match_stream, percentiles, release_rig, stop_drive

from ff_hwbridge.drive.epos import EposMaster
from ff_hwbridge.drive.player import PlayerConfig, SetpointPlayer
from ff_hwbridge.sim.rig_process import RigProcess, free_port, rig_master_config


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0, help="s of streaming")
    ap.add_argument("--rate", type=float, default=1000.0, help="setpoints per second")
    ap.add_argument("--sync-period", type=float, default=0.001, help="s")
    ap.add_argument("--family", default="epos4", choices=("epos4", "epos2"))
    ap.add_argument("--sim-switch-interval", type=float, default=0.0005,
                    help="s, python thread switch interval in the simulator (the rig CLI default)")
    ap.add_argument("--sim-rt-priority", type=int, default=0,
                    help="run the simulator process under SCHED_FIFO at this priority (chrt -f)")
    ap.add_argument("--rt-priority", "--master-rt-priority", dest="rt_priority", type=int,
                    default=0, help="SCHED_FIFO priority of the master's scheduler thread (0 = off)")
    ap.add_argument("--switch-interval", type=float, default=0.0,
                    help="s, sys.setswitchinterval for this (master) process (0 = python's 5 ms)")
    ap.add_argument("--spin-margin", type=float, default=None,
                    help="s, scheduler busy-wait before each stamp (default: the config's)")
    ap.add_argument("--prepare", default="on", choices=("on", "off"),
                    help="on: clamp + convert each setpoint ahead of its stamp (scheduler prepare "
                         "step, as the bridge node); off: all of it at the stamp")
    ap.add_argument("--hub", default="sim", choices=("sim", "process"),
                    help="host the hub in the simulator process (as ff_sim_driver does) or in "
                         "a process of its own")
    ap.add_argument("--timing", default="on_receipt", choices=("on_receipt", "sync"),
                    help="setpoint_timing of the master: on_receipt (RPDO at each stamp, what this "
                         "benchmark measures) or sync (latched at SYNC: benchmarks/bench_sync.py)")
    a = ap.parse_args()
    if a.switch_interval > 0:
        sys.setswitchinterval(a.switch_interval)

    port = free_port()
    url = f"ws://127.0.0.1:{port}/"
    record = os.path.join(tempfile.mkdtemp(prefix="ff-bench-can-"), "sim.json")
    hub = None
    if a.hub == "process":
        hub = subprocess.Popen([sys.executable, "-u", "-m", "ff_hwbridge.cli.can_hub", "--port", str(port)],
                               stdout=subprocess.PIPE, text=True)
        assert hub.stdout is not None
        hub.stdout.readline()
    load_before = os.getloadavg()
    rt = ["chrt", "-f", str(a.sim_rt_priority)] if a.sim_rt_priority > 0 else []
    sim = RigProcess(["--family", a.family, "--record", record,
                      "--switch-interval", str(a.sim_switch_interval)],
                     port=port, host_hub=a.hub == "sim", bus_url=url, prefix=rt)
    master = None
    try:
        settings = {"sync_period": a.sync_period, "heartbeat_producer_ms": 10,
                    # a timing benchmark, not a safety test: tolerate a loaded machine holding
                    # a process off
                    "heartbeat_timeout": 1.0, "feedback_timeout": 1.0, "setpoint_timeout": 1.0,
                    "setpoint_timing": a.timing}
        if a.spin_margin is not None:
            settings["spin_margin"] = a.spin_margin
        cfg = rig_master_config(url, a.family, 10.0, **settings)
        master = EposMaster(cfg)
        if not enable_drive(master):
            raise SystemExit(f"drive not enabled: {master.fault_reason}")
        tpdo_count = {"n": 0}
        assert master.network is not None      # connected
        master.network.subscribe(0x181, lambda i, d, t: tpdo_count.__setitem__("n", tpdo_count["n"] + 1))

        # small alternating currents (±0.3 A pattern): unique-enough raw values, arm barely moves
        n = int(a.duration * a.rate)
        pattern = [(((k * 37) % 61) - 30) * 0.01 for k in range(n)]   # period 61, |I| <= 0.3 A
        # the bridge node's path; --prepare off: clamp, convert and send all at the stamp
        player = SetpointPlayer(master, PlayerConfig(spin_margin=cfg.spin_margin,
                                                     rt_priority=a.rt_priority,
                                                     prepare_ahead=a.prepare == "on")).start()
        t0 = time.time_ns() + 500_000_000
        period = int(1e9 / a.rate)
        stamps = [t0 + k * period for k in range(n)]
        sync0, tw0 = tpdo_count["n"], time.monotonic()
        feed_stream(player, stamps, pattern)      # a motion: feeds the setpoint watchdog
        time.sleep(0.2)
        tpdos, window = tpdo_count["n"] - sync0, time.monotonic() - tw0
        sent_stats = player.stats().as_dict()
        sent_at = {stamp: sent for stamp, sent in player.records()}
        rt_active = bool(player.diagnostics()["scheduler_realtime"])
        latched = stop_drive(player, master)
    finally:
        release_rig(master, sim)
        if hub is not None:
            hub.terminate()
            hub.wait(10)

    with open(record) as fh:
        rec = json.load(fh)
    arrivals = rec["setpoints"]["1"]
    # Match the stream in the drive's arrival log, in order, by raw value. The enable sequence
    # sends RPDOs (setpoint 0) before it; anything else the drive received that the scheduler did
    # not schedule (the master's periodic RPDO refresh, or a repeated older setpoint) is counted
    # as "extra".
    units = master.units[0]
    want = [units.amps_to_setpoint(x, limit=10.0) for x in pattern]
    start, found, unexpected = match_stream([r[2] for r in arrivals], want, n)
    matched = [(k, arrivals[i]) for k, i in found]     # (stream index k, arrival record)
    result: dict = {"benchmark": "bench_can_stream", "host": platform.node(),
                    "cpus": os.cpu_count(), "duration_s": a.duration, "rate_hz": a.rate,
                    "family": a.family, "transport": "python-can-remote hub on 127.0.0.1",
                    "hub_in": a.hub, "sim_switch_interval_s": a.sim_switch_interval or 0.005,
                    "sim_rt_priority": a.sim_rt_priority, "master_rt_priority": a.rt_priority if rt_active else 0,
                    "master_switch_interval_s": sys.getswitchinterval(),
                    "spin_margin_s": cfg.spin_margin, "prepare_step": a.prepare == "on",
                    "loadavg_1min_before_after": [load_before[0], os.getloadavg()[0]],
                    "setpoints_sent": n, "safe_state": latched}
    if start is None:
        result["error"] = "stream not found in the drive's arrival log"
    else:
        lost = n - len(matched)
        err_us = np.array([(r[1] - stamps[k]) / 1000.0 for k, r in matched])
        transport_us = np.array([(r[1] - sent_at[stamps[k]]) / 1000.0 for k, r in matched
                                 if stamps[k] in sent_at])
        result.update({
            "setpoints_received": len(matched), "lost": lost,
            "extra_rpdos_inside_stream": unexpected,
            "switch_error_us": percentiles(err_us),
            "jitter_us": percentiles(err_us - np.median(err_us)) if err_us.size else {},
            "sent_error_us": sent_stats,
            "transport_us": percentiles(transport_us),
            "feedback": {"window_s": window, "syncs_expected": int(window / a.sync_period),
                         "tpdo1_received": tpdos},
            "sim_link_stats": rec["link_stats"]["1"],
        })
        p99 = result["switch_error_us"].get("p99", float("inf"))
        result["goal_p99_le_250us"] = bool(p99 <= 250.0)
        result["goal_zero_lost"] = lost == 0
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

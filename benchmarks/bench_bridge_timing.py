"""Bridge benchmark: sustained stamped-setpoint streaming to a simulated EPOS over the CAN hub.

Starts the simulated rig (``python -m ff_hwbridge.sim_rig --host-hub PORT``, its own process,
hosting the loopback CAN hub), connects an :class:`~ff_hwbridge.epos.EposMaster` to it over
python-can-remote, enables the drive, and streams setpoints at ``--rate`` Hz for ``--duration``
s through the :class:`~ff_hwbridge.scheduler.StampScheduler`, each stamped on a 1/rate grid.
Currents stay below the stiction edge of the arm (~0.17 A) so the arm does not wander.

Prints JSON: frames sent / received by the drive / lost, and the switch-time error
(stamp -> the moment the simulated drive applied the RPDO, wall clock, µs): p50 / p99 / max;
plus the bridge-side error (stamp -> RPDO handed to the bus) and late counts.

    .venv/bin/python benchmarks/bench_bridge_timing.py --duration 60 --rate 1000
"""
from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time

import numpy as np

from ff_hwbridge.cia402 import State
from ff_hwbridge.config import load_config
from ff_hwbridge.epos import EposMaster
from ff_hwbridge.scheduler import StampScheduler

NOMINAL = 3.0      # A, matches the sim's default nominal current


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_line(proc: subprocess.Popen, text: str, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if not line:
            return False
        if text in line:
            return True
    return False


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0, help="s of streaming")
    ap.add_argument("--rate", type=float, default=1000.0, help="setpoints per second")
    ap.add_argument("--sync-period", type=float, default=0.001, help="s")
    ap.add_argument("--spin-margin", type=float, default=0.0003, help="s")
    ap.add_argument("--rt-priority", type=int, default=0, help="SCHED_FIFO priority of the scheduler thread (0 = off)")
    ap.add_argument("--switch-interval", type=float, default=0.0,
                    help="s, sys.setswitchinterval for this process (0 = python's default 5 ms)")
    a = ap.parse_args()
    if a.switch_interval > 0:
        sys.setswitchinterval(a.switch_interval)

    port = _free_port()
    record = os.path.join(tempfile.mkdtemp(prefix="ff-bench-"), "setpoints.json")
    sim = subprocess.Popen([sys.executable, "-u", "-m", "ff_hwbridge.sim_rig", "--host-hub", str(port),
                            "--model", "arm1dof", "--node-ids", "1", "--record", record],
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                           text=True)
    master = None
    try:
        if not _wait_line(sim, "sim rig ready", 30.0):
            print(json.dumps({"error": "simulated rig did not start"}))
            return 1
        cfg = load_config({
            "bus": {"interface": "remote", "channel": f"ws://127.0.0.1:{port}/"},
            "joints": [{"name": "joint1", "node_id": 1, "family": "epos4", "current_limit": 10.0,
                        "units": {"nominal_current": NOMINAL, "torque_constant": 0.0267,
                                  "counts_per_rev": 2048, "gear_ratio": 54.0}}],
            "sync_period": a.sync_period, "heartbeat_producer_ms": 20, "heartbeat_timeout": 1.0,
            "feedback_timeout": 1.0,     # this measures streaming; a stalled sim must not end it
            "setpoint_timeout": 1.0, "spin_margin": a.spin_margin})
        master = EposMaster(cfg)
        master.connect()
        master.configure()
        master.enable()
        if not master.wait_for_state(State.OPERATION_ENABLED, 3.0):
            print(json.dumps({"error": f"drive not enabled: {master.states()} {master.fault_reason}"}))
            return 1
        # currents: 40 distinct values 5..160 mA-ish (raw per mille 2..53), alternating sign
        n = int(round(a.duration * a.rate))
        raws = np.array([(2 + (k % 26) * 2) * (1 if (k // 26) % 2 == 0 else -1) for k in range(n)])
        amps = raws * NOMINAL / 1000.0
        sched = StampScheduler(lambda stamp, prepared: master.send_prepared(prepared),
                               spin_margin=a.spin_margin, rt_priority=a.rt_priority,
                               prepare=lambda i: master.prepare_currents([amps[i]])).start()
        period_ns = int(round(1e9 / a.rate))
        t0 = (time.time_ns() // period_ns + int(0.5e9 // period_ns)) * period_ns   # on the grid
        stamps = t0 + period_ns * np.arange(n, dtype=np.int64)
        # feed the scheduler ~100 ms ahead, as the executor would
        k = 0
        while k < n:
            horizon = time.time_ns() + 100_000_000
            while k < n and stamps[k] <= horizon:
                sched.submit(int(stamps[k]), k)
                master.note_setpoint(motion_running=True)
                k += 1
            time.sleep(0.01)
        while sched.pending:
            time.sleep(0.01)
        time.sleep(0.2)
        bridge = sched.stats()
        sched.stop()
        latched = master.fault_reason
        master.command_zero()
        master.disable()
        time.sleep(0.05)
        master.disconnect()
        master = None
        sim.stdin.write("quit\n")
        sim.stdin.flush()
        sim.wait(30)
        with open(record, encoding="utf-8") as fh:
            log = json.load(fh)["setpoints"]["1"]
        # match arrivals to the stream: in order, by raw value
        arrivals = [(wall, raw) for _, wall, raw, _ in log if wall >= t0 - 1_000_000]
        err_ns, j, repeats = [], 0, 0
        for wall, raw in arrivals:
            if raw == 0:                 # not a streamed value (enable / safe state)
                continue
            if j > 0 and raw == raws[j - 1] and (j >= n or raw != raws[j]):
                repeats += 1             # the master's RPDO refresh repeating the last value
                continue
            k = j
            while k < n and k < j + 52 and raws[k] != raw:   # skip lost ones (pattern: 52)
                k += 1
            if k >= n or raws[k] != raw:
                continue
            err_ns.append(wall - int(stamps[k]))
            j = k + 1
        err = np.asarray(err_ns, dtype=float) / 1000.0
        received = len(err_ns)
        out = {
            "benchmark": "bridge_timing", "rate_hz": a.rate, "duration_s": a.duration,
            "sync_period_s": a.sync_period, "transport": "python-can-remote hub on 127.0.0.1",
            "sent": int(bridge.count), "received_by_drive": received, "lost": int(n - received),
            "repeated_by_refresh": repeats,
            "switch_error_us": {"p50": float(np.percentile(err, 50)), "p99": float(np.percentile(err, 99)),
                                "max": float(err.max()), "min": float(err.min())} if received else None,
            "bridge_send_error_us": {"p50": bridge.p50_us, "p99": bridge.p99_us, "max": bridge.max_us},
            "late_over_500us": bridge.late, "stale": bridge.stale, "spin_margin_s": a.spin_margin,
            "rt_priority": a.rt_priority if sched.rt_active else 0,
            "switch_interval_s": sys.getswitchinterval(),
            "safe_state": latched, "cpu_count": os.cpu_count(),
            "load_avg_1min": os.getloadavg()[0],
        }
        print(json.dumps(out, indent=1))
        return 0
    finally:
        if master is not None:
            master.disconnect()
        if sim.poll() is None:
            sim.terminate()
            try:
                sim.wait(10)
            except subprocess.TimeoutExpired:
                sim.kill()


if __name__ == "__main__":
    sys.exit(main())

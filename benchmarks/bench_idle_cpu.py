"""CPU an idle simulated stack costs, per process; JSON.

Starts the stack (``ff_executor.bringup.stack``: CAN hub, simulated drive + arm, bridge active,
executor; no planner unless ``--planner``), waits ``--settle`` s, then reads each process's user +
system CPU time (``/proc/PID/stat``, its threads and finished children included) over
``--window`` s with nothing commanded. A stack that burns CPU while idle leaves less of a small
machine to the processes that must keep time. ``uptime`` at the start and the end.

    python benchmarks/bench_idle_cpu.py [--window 20] [--settle 5] [--planner] [--out FILE]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import tempfile
import time
from typing import Optional

from _common import log, report

from ff_executor.bringup.stack import Stack, StackOptions

TICKS = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> Optional[float]:
    """User + system CPU s of ``pid`` (all its threads) and its reaped children; None if gone."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    # fields after the command: state(0) ... utime(11) stime(12) cutime(13) cstime(14)
    return sum(int(fields[i]) for i in (11, 12, 13, 14)) / TICKS


def children(pid: int) -> list[int]:
    """Live child processes of ``pid`` (e.g. the bridge's setpoint player process)."""
    try:
        out = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True, check=False)
    except OSError:
        return []
    return [int(x) for x in out.stdout.split()]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--window", type=float, default=20.0, help="s of idle CPU measured (default 20)")
    ap.add_argument("--settle", type=float, default=5.0, help="s waited after start-up (default 5)")
    ap.add_argument("--planner", action="store_true", help="start the planner node too")
    ap.add_argument("--out", default=None, help="also write the JSON here")
    a = ap.parse_args()
    load_start = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="ff-idle-") as run_dir, \
            Stack(StackOptions(run_dir=run_dir, planner=a.planner), log=log) as stack:
        time.sleep(a.settle)
        procs = {p.name: p.pid for p in stack.procs}
        for name, pid in list(procs.items()):
            for i, child in enumerate(children(pid)):
                procs[f"{name}/child{i}"] = child
        before = {n: cpu_seconds(pid) for n, pid in procs.items()}
        t0 = time.monotonic()
        time.sleep(a.window)
        wall = time.monotonic() - t0
        after = {n: cpu_seconds(pid) for n, pid in procs.items()}
    per = {n: round(100.0 * (after[n] - before[n]) / wall, 1)
           for n in procs if before[n] is not None and after[n] is not None}
    report({"what": "idle simulated stack: CPU per process, % of one core",
            "window_s": round(wall, 2), "cpu_percent": per,
            "total_percent": round(sum(per.values()), 1), "cores": os.cpu_count(),
            "load_start": [round(x, 2) for x in load_start],
            "load_end": [round(x, 2) for x in os.getloadavg()]}, a.out)


if __name__ == "__main__":
    main()

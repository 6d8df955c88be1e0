"""Benchmark ff-library build (issue 9); prints JSON.

* tasks per minute with 1 and 2 Dask worker processes (LocalCluster on 127.0.0.1) on a 1-DOF grid,
  and the scaling ratio (cluster start-up and worker warm-up excluded; reported separately);
* the speed-up of neighbour continuation over cold multistart on the same grid (same executor:
  one worker), with what each solved.

    .venv/bin/python benchmarks/bench_library_build.py [--grid GRID.yaml] [--workers 1 2] [--repeat 1]

Every build writes a fresh library in a temporary folder. On a shared machine the figures move
with the load: the JSON carries the core count and the load average.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

from ff_planner.library_build import build_library, start_local_cluster
from ff_planner.library_grid import describe, expand, load_grid, parse_grid

# 1-DOF, paper table 2 arm, all three friction parameters uncertain (k = 3, N = 5): moves of
# 0.7 ... 1.2 rad in 0.9 ... 1.2 s (DESIGN.md: robust N = 5 plans exist around 1 rad in 1 s).
DEFAULT_GRID = {
    "name": "bench-arm1dof-k3", "model": "arm1dof", "preset": "table2", "objective": "robust-derivative",
    "uncertain": ["pv", "pc", "pt"], "steps": 5, "starts": 400, "seed": 0, "time_budget": 60,
    "q0": 0.0, "qf": {"start": 0.7, "stop": 1.2, "step": 0.1}, "tf": {"start": 0.9, "stop": 1.2, "step": 0.1},
}


def _warm_workers(client) -> float:
    """Import the planner and plan one small task in every worker (JIT caches); returns s."""
    def warm() -> int:
        from ff_planner.library_build import plan_for_library
        from ff_planner.profile import PlanRequest

        try:
            plan_for_library(PlanRequest(q0=[0.0], qf=[0.5], tf=1.0, uncertain=["pc"], starts=20,
                                         time_budget=20))
        except Exception:
            pass
        return os.getpid()

    t0 = time.perf_counter()
    client.run(warm)
    return time.perf_counter() - t0


def run_build(grid_data: dict, workers: int, continuation: bool, tmp: Path, tag: str) -> dict:
    t0 = time.perf_counter()
    cluster, client = start_local_cluster(workers)
    startup = time.perf_counter() - t0
    try:
        warm = _warm_workers(client)
        rep = build_library(expand(parse_grid(grid_data)), tmp / f"{tag}.sqlite", client=client,
                            continuation=continuation, progress=False)
    finally:
        client.close()
        cluster.close()
    d = rep.to_dict()
    return {"workers": workers, "continuation": continuation, "cluster_start_s": startup,
            "worker_warmup_s": warm, "wall_s": rep.wall_time, "tasks_per_minute": rep.tasks_per_minute,
            "distinct_tasks": rep.distinct_solved, "planner_time_sum_s": rep.solve_time,
            "solved": rep.solved, "infeasible": rep.infeasible, "failed": rep.failed,
            "solved_how": d["how"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--grid", default=None, help="grid YAML (default: the built-in 1-DOF k = 3 grid)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeat", type=int, default=1, help="builds per setting (the best is kept)")
    a = ap.parse_args(argv)
    grid_data = DEFAULT_GRID
    if a.grid:
        import yaml

        grid_data = yaml.safe_load(Path(a.grid).read_text())
    load_grid(grid_data)
    info = describe(expand(parse_grid(grid_data)))
    out = {"benchmark": "ff-library build", "grid": {k: v for k, v in grid_data.items()}, "grid_info": info,
           "cpu_count": os.cpu_count(), "loadavg_before": list(os.getloadavg()),
           "python": platform.python_version(), "runs": []}
    with tempfile.TemporaryDirectory(prefix="ff-bench-library-") as td:
        tmp = Path(td)
        best: dict = {}
        for cont in (True, False):
            for w in (a.workers if cont else a.workers[:1]):
                for r in range(a.repeat):
                    res = run_build(grid_data, w, cont, tmp, f"w{w}-c{int(cont)}-r{r}")
                    out["runs"].append(res)
                    print(json.dumps(res), file=sys.stderr)
                    k = (w, cont)
                    if k not in best or res["wall_s"] < best[k]["wall_s"]:
                        best[k] = res
    w1 = a.workers[0]
    out["tasks_per_minute"] = {str(w): best[(w, True)]["tasks_per_minute"] for w in a.workers}
    if len(a.workers) > 1:
        w2 = a.workers[1]
        out["scaling_ratio"] = best[(w2, True)]["tasks_per_minute"] / best[(w1, True)]["tasks_per_minute"]
        out["scaling_note"] = f"tasks/min with {w2} workers over {w1} worker(s); ideal {w2 / w1:g}"
    c, cold = best[(w1, True)], best[(w1, False)]
    out["continuation_vs_cold"] = {
        "workers": w1, "wall_speedup": cold["wall_s"] / c["wall_s"] if c["wall_s"] > 0 else None,
        "planner_time_speedup": (cold["planner_time_sum_s"] / c["planner_time_sum_s"]
                                 if c["planner_time_sum_s"] > 0 else None),
        "continuation": {k: c[k] for k in ("wall_s", "planner_time_sum_s", "solved", "infeasible", "failed",
                                           "solved_how")},
        "cold_multistart": {k: cold[k] for k in ("wall_s", "planner_time_sum_s", "solved", "infeasible",
                                                 "failed", "solved_how")},
    }
    out["loadavg_after"] = list(os.getloadavg())
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark ff-library build (issue 9); prints JSON on stdout (progress lines on stderr).

1. Scaling: tasks per minute with 1 and 2 Dask worker processes (LocalCluster on 127.0.0.1) on a
   1-DOF grid of heavier tasks (robust-sampled, N = 8: about a second each), with neighbour
   continuation (the normal build) and without it (independent tasks); the scaling ratio.
   Cluster start-up and worker warm-up (imports, JIT caches) are excluded and reported apart;
   the clusters are started together and their builds alternate, round after round, so that a
   change in machine load hits every setting alike.
   The scaling grid is built with and without continuation, so it gives a second continuation
   figure (robust-sampled).
2. Continuation vs cold multistart on the same 1-DOF grid (robust-derivative, k = 3, N = 5,
   189 tasks) on one worker: wall time, task time, and how many tasks each solved. Runs are
   interleaved and repeated; the best of each is kept, and the per-round ratios are listed.

    .venv/bin/python benchmarks/bench_library_build.py [--quick] [--repeat 2]

Every build writes a fresh library in a temporary folder. On a shared machine the figures move
with the load: the JSON carries the core count and load averages.
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

from ff_planner.library.build import build_library, start_local_cluster
from ff_planner.library.grid import describe, expand, parse_grid

SCALING_GRID = {
    "name": "bench-scaling", "model": "arm1dof", "preset": "table2", "objective": "robust-sampled",
    "uncertain": ["pv", "pc", "pt"], "steps": 8, "starts": 200, "seed": 0, "time_budget": 120,
    "q0": 0.0, "qf": {"start": 0.8, "stop": 1.3, "step": 0.1}, "tf": [1.0, 1.1],
}
CONTINUATION_GRID = {
    "name": "bench-continuation", "model": "arm1dof", "preset": "table2", "objective": "robust-derivative",
    "uncertain": ["pv", "pc", "pt"], "steps": 5, "starts": 400, "seed": 0, "time_budget": 60,
    "q0": 0.0, "qf": {"start": 0.5, "stop": 1.5, "step": 0.05}, "tf": {"start": 0.8, "stop": 1.2, "step": 0.05},
}
QUICK = {"qf": {"start": 0.8, "stop": 1.1, "step": 0.1}, "tf": [1.0, 1.1]}


def _warm_workers(client) -> float:
    """Import the planner and plan small tasks in every worker (JIT caches); returns s."""
    def warm() -> int:
        from ff_planner.model.profile import PlanRequest
        from ff_planner.optimize.planner import plan

        for obj, unc, n in (("robust-derivative", ["pc"], None), ("robust-derivative", ["pv", "pc", "pt"], 5),
                            ("robust-sampled", ["pv", "pc", "pt"], 6)):
            try:
                plan(PlanRequest(q0=[0.0], qf=[1.0], tf=1.0, uncertain=unc, steps=n, starts=50,
                                 objective=obj, time_budget=30))
            except Exception:
                pass
        return os.getpid()

    t0 = time.perf_counter()
    client.run(warm)
    return time.perf_counter() - t0


def _build(client, grid_data: dict, continuation: bool, path: Path) -> dict:
    rep = build_library(expand(parse_grid(grid_data)), path, client=client, continuation=continuation,
                        progress=False)
    w = max(1, rep.workers)
    return {"continuation": continuation, "wall_s": rep.wall_time, "tasks_per_minute": rep.tasks_per_minute,
            # sum of task times / (workers × wall): how busy Dask kept the workers (1 = always)
            "worker_busy_fraction": rep.solve_time / (w * rep.wall_time) if rep.wall_time > 0 else None,
            "distinct_tasks": rep.distinct_solved, "task_time_sum_s": rep.solve_time,
            "solved": rep.solved, "infeasible": rep.infeasible, "failed": rep.failed,
            "solved_how": dict(rep.how), "loadavg_1min": os.getloadavg()[0]}


def _best(runs: list[dict]) -> dict:
    return min(runs, key=lambda r: r["wall_s"])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeat", type=int, default=2, help="rounds (the best of each setting is kept)")
    ap.add_argument("--quick", action="store_true", help="small grids (a smoke run)")
    a = ap.parse_args(argv)
    sgrid = {**SCALING_GRID, **(QUICK if a.quick else {})}
    cgrid = {**CONTINUATION_GRID, **(QUICK if a.quick else {})}
    out: dict = {"benchmark": "ff-library build", "cpu_count": os.cpu_count(),
                 "loadavg_before": list(os.getloadavg()), "python": platform.python_version(),
                 "scaling": {"grid": sgrid, "grid_info": describe(expand(parse_grid(sgrid))), "runs": []},
                 "continuation_vs_cold": {"grid": cgrid, "grid_info": describe(expand(parse_grid(cgrid))),
                                          "workers": a.workers[0], "runs": []}}
    runs: dict = {}
    clusters: dict = {}
    with tempfile.TemporaryDirectory(prefix="ff-bench-library-") as td:
        tmp = Path(td)
        try:
            for w in a.workers:   # all clusters up first; builds then alternate between them, so
                t0 = time.perf_counter()             # a change in machine load hits every setting
                cluster, client = start_local_cluster(w)
                startup = time.perf_counter() - t0
                clusters[w] = (cluster, client, startup, _warm_workers(client))
            n = 0
            for r in range(a.repeat):
                for cont in (True, False):
                    for w in a.workers:
                        n += 1
                        _, client, startup, warm = clusters[w]
                        res = {"workers": w, "round": r, "cluster_start_s": startup, "worker_warmup_s": warm,
                               **_build(client, sgrid, cont, tmp / f"s{n}.sqlite")}
                        out["scaling"]["runs"].append(res)
                        runs.setdefault(("s", w, cont), []).append(res)
                        print(json.dumps(res), file=sys.stderr, flush=True)
                for cont in (True, False):
                    n += 1
                    w = a.workers[0]
                    res = {"workers": w, "round": r, **_build(clusters[w][1], cgrid, cont, tmp / f"c{n}.sqlite")}
                    out["continuation_vs_cold"]["runs"].append(res)
                    runs.setdefault(("c", w, cont), []).append(res)
                    print(json.dumps(res), file=sys.stderr, flush=True)
        finally:
            for cluster, client, _, _ in clusters.values():
                client.close()
                cluster.close()
    s = out["scaling"]
    for cont, name in ((True, "with_continuation"), (False, "independent_tasks")):
        tpm = {str(w): _best(runs[("s", w, cont)])["tasks_per_minute"] for w in a.workers}
        s[name] = {"tasks_per_minute_best": tpm}
        if len(a.workers) > 1:
            w1, w2 = a.workers[0], a.workers[1]
            s[name]["scaling_ratio_best"] = tpm[str(w2)] / tpm[str(w1)] if tpm[str(w1)] else None
            s[name]["scaling_ratio_per_round"] = [
                b["tasks_per_minute"] / x["tasks_per_minute"]
                for x, b in zip(runs[("s", w1, cont)], runs[("s", w2, cont)]) if x["tasks_per_minute"]]
            s[name]["ideal_ratio"] = w2 / w1
    w1 = a.workers[0]
    c, cold = _best(runs[("c", w1, True)]), _best(runs[("c", w1, False)])
    keys = ("wall_s", "task_time_sum_s", "solved", "infeasible", "failed", "solved_how")
    out["continuation_vs_cold"].update({
        "wall_speedup_best": cold["wall_s"] / c["wall_s"] if c["wall_s"] > 0 else None,
        "wall_speedup_per_round": [b["wall_s"] / x["wall_s"] for x, b in
                                   zip(runs[("c", w1, True)], runs[("c", w1, False)]) if x["wall_s"] > 0],
        "task_time_speedup_best": (cold["task_time_sum_s"] / c["task_time_sum_s"]
                                   if c["task_time_sum_s"] > 0 else None),
        "extra_tasks_solved": c["solved"] - cold["solved"],
        "continuation": {k: c[k] for k in keys}, "cold_multistart": {k: cold[k] for k in keys}})
    # the scaling grid (robust-sampled) was also built with and without continuation on w1
    sc, scold = _best(runs[("s", w1, True)]), _best(runs[("s", w1, False)])
    out["scaling"]["continuation_vs_cold"] = {
        "workers": w1, "wall_speedup_best": scold["wall_s"] / sc["wall_s"] if sc["wall_s"] > 0 else None,
        "wall_speedup_per_round": [b["wall_s"] / x["wall_s"] for x, b in
                                   zip(runs[("s", w1, True)], runs[("s", w1, False)]) if x["wall_s"] > 0],
        "extra_tasks_solved": sc["solved"] - scold["solved"]}
    out["loadavg_after"] = list(os.getloadavg())
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

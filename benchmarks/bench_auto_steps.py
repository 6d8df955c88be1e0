"""Benchmark: the planner chooses N and the starts itself; prints one JSON document.

Table 2 arm, pv pc pt uncertain (k = 3), robust-box objective, ±20 % box. Tasks: goals 0.25 …
2.0 rad in tf = 1 s, and goal 1 rad in tf = 0.6 … 1.5 s. Per task and mode:
- ``steps0``: steps = 0, starts = 0 — the smallest N from 2 + k up to 12 whose plan is truly
  robust (zero exact derivatives, verified) with a box worst ≤ 5 mrad, starts escalated
  50 → 200 → 1000 before N; else the least-worst robust plan; else NO_ROBUST_PLAN with the best
  plan labelled;
- ``default``: the default request (steps unset: N = 8, other N only while no truly robust
  plan is found; starts 50 escalated before N).
Figures: N chosen, starts used (total LM starts and the ladder rows), worst rest error over the
box judged on 8 corners + centre + 256 uniform points (seed 0), the plan's error code and
whether it is labelled best effort, plan time (in-process, kernels loaded first), and what the
planner tried (``extra["auto"]["tried"]``).

Usage: python benchmarks/bench_auto_steps.py [--modes steps0 default] [--goals ...] [--tfs ...]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from typing import Any

from _common import report
from bench_box_robust import judge_box, worst_rest

from ff_planner.model.profile import PlanRequest
from ff_planner.optimize.planner import plan

GOALS = (0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0)     # rad, tf = 1 s
TFS = (0.6, 0.7, 0.8, 0.9, 1.0, 1.2, 1.5)                 # s, goal 1 rad
MODES: dict[str, dict[str, Any]] = {"steps0": dict(steps=0, starts=0), "default": {}}


def one(qf: float, tf: float, mode: str, scales, budget: float) -> dict:
    t0 = time.perf_counter()
    r = plan(PlanRequest(qf=(qf,), tf=tf, time_budget=budget, **MODES[mode]))
    dt = time.perf_counter() - t0
    auto = (r.extra or {}).get("auto") or {}
    row = {"qf_rad": qf, "tf_s": tf, "mode": mode, "error_code": r.error_code,
           "truly_robust": bool(r.success and r.robust), "best_effort": bool(r.best_effort),
           "steps_chosen": r.profile.n_steps if r.profile is not None else None,
           "starts_used": int(r.starts_tried), "plan_time_s": dt,
           "tried": [{k: v for k, v in t.items() if k != "time_s"} for t in auto.get("tried", [])],
           "box_target_met": auto.get("box_target_met")}
    if r.profile is not None:
        row["worst_rest_error_rad"] = worst_rest(r, scales)
        row["coast_s"] = float(r.profile.coast)
        row["max_abs_derivative"] = (r.extra.get("verification") or {}).get("max_abs_derivative")
    if not (r.success and r.robust):
        row["label"] = r.message[:300]
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES))
    ap.add_argument("--goals", nargs="*", type=float, default=list(GOALS))
    ap.add_argument("--tfs", nargs="*", type=float, default=list(TFS))
    ap.add_argument("--time-budget", type=float, default=60.0, help="s per plan (default 60)")
    ap.add_argument("--out", default=None, help="also write the JSON here")
    a = ap.parse_args()
    load0 = os.getloadavg()[0]
    scales = judge_box()
    plan(PlanRequest(steps=5, starts=5))                  # compile / load the kernels
    tasks = [(g, 1.0) for g in a.goals] + [(1.0, t) for t in a.tfs if (1.0, t) not in
                                           [(g, 1.0) for g in a.goals]]
    rows = []
    for mode in a.modes:
        for qf, tf in tasks:
            rows.append(one(qf, tf, mode, scales, a.time_budget))
            print(json.dumps(rows[-1]), flush=True, file=sys.stderr)     # progress, row by row
    out = {"benchmark": "auto_steps", "model": "arm1dof table 2, pv pc pt, +-20 % box",
           "judge": "rest position: 8 corners + centre + 256 uniform (seed 0)",
           "rows": rows, "load_1min_before": load0, "load_1min_after": os.getloadavg()[0],
           "cores": os.cpu_count()}
    report(out, a.out, final_newline=True)


if __name__ == "__main__":
    main()

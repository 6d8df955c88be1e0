"""Benchmark of position and speed limits on the paper task; prints one JSON document.

Task: table 2 arm, 0 → 1 rad in 1 s, pv pc pt uncertain, ±20 % box, robust-box with N = 12
(``steps=12``: one planner run per request, no N ladder). Limits per cell: position range
[q_min, 1.05] rad for q_min in 0, −0.3, −0.6, −1 (or no position limit) × speed limit 2, 4, 8
rad/s (or none); plans over ``--seeds`` seeds in-process (kernels compiled first).

Per plan, from its own certificate (``certify_1dof``: nominal, corners + centre, 3^3 grid, 256
uniform points, the per-parameter lines): the certified worst rest error, the excursion (lowest
and highest position, peak speed, worst over those points) and whether it keeps within the
limits there; what the planner answered (truly robust; least-worst within the limits, not
derivative-robust; refused) and the plan time (wall and CPU of this process; on a shared machine
read the CPU figure). Per cell: medians over the seeds.

Usage: python benchmarks/bench_limits.py [--seeds 3] [--out FILE]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time
from typing import Optional

import numpy as np

from ff_planner.model.limits import MotionLimits
from ff_planner.model.profile import PlanRequest
from ff_planner.optimize.planner import plan

Q_MAX = 1.05
Q_MINS: tuple[Optional[float], ...] = (0.0, -0.3, -0.6, -1.0, None)
V_MAXS: tuple[Optional[float], ...] = (2.0, 4.0, 8.0, None)


def _limits(q_min: Optional[float], v_max: Optional[float]) -> Optional[MotionLimits]:
    if q_min is None and v_max is None:
        return None
    return MotionLimits.of(None if q_min is None else [q_min], None if q_min is None else [Q_MAX],
                           None if v_max is None else [v_max])


def _one(q_min: Optional[float], v_max: Optional[float], seed: int) -> dict:
    lim = _limits(q_min, v_max)
    req = PlanRequest(seed=seed, steps=12, limits=lim, time_budget=60.0)
    t0, c0 = time.perf_counter(), time.process_time()
    r = plan(req)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    row: dict = {"seed": seed, "wall_s": wall, "cpu_s": cpu, "success": bool(r.success),
                 "robust": bool(r.robust), "error_code": r.error_code}
    if r.success and r.robust:
        row["answer"] = "truly robust"
    elif r.profile is not None:
        row["answer"] = "least worst within the limits (not derivative-robust)"
    else:
        row["answer"] = "refused"
        row["message"] = r.message
    c = r.certificate
    if c is not None and c.excursion is not None:
        ex = c.excursion
        row.update(worst_rest_error=c.worst_rest_error, worst_min=ex.worst_min[0],
                   worst_max=ex.worst_max[0], worst_speed=ex.worst_speed[0],
                   nominal_min=ex.nominal_min[0], nominal_max=ex.nominal_max[0],
                   nominal_speed=ex.nominal_speed[0], violations=ex.violations(lim),
                   certificate_points=c.samples)
    return row


def _median(rows: list[dict], key: str) -> Optional[float]:
    xs = [r[key] for r in rows if key in r and r[key] is not None and math.isfinite(r[key])]
    return float(np.median(xs)) if xs else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    plan(PlanRequest(seed=0, steps=12, limits=_limits(-0.3, 4.0)))     # compile / load kernels
    load0 = os.getloadavg()[0]
    cells = []
    for q_min in Q_MINS:
        for v_max in V_MAXS:
            rows = [_one(q_min, v_max, s) for s in range(args.seeds)]
            cell = {"q_min": q_min, "q_max": None if q_min is None else Q_MAX, "qd_max": v_max,
                    "answers": sorted({r["answer"] for r in rows}),
                    "all_within_limits": all(r.get("violations") == [] for r in rows
                                             if "violations" in r),
                    "worst_rest_error_median_mrad": None, "plan_wall_s_median":
                        _median(rows, "wall_s"), "plan_cpu_s_median": _median(rows, "cpu_s")}
            w = _median(rows, "worst_rest_error")
            cell["worst_rest_error_median_mrad"] = None if w is None else 1e3 * w
            for k in ("worst_min", "worst_max", "worst_speed"):
                cell[f"{k}_median"] = _median(rows, k)
            cell["runs"] = rows
            cells.append(cell)
            print(f"q_min {q_min} qd_max {v_max}: {cell['answers']} "
                  f"worst {cell['worst_rest_error_median_mrad']} mrad, "
                  f"cpu {cell['plan_cpu_s_median']:.2f} s", flush=True, file=__import__("sys").stderr)
    doc = {"task": "table 2 arm, 0 -> 1 rad in 1 s, pv pc pt, +-20 % box, robust-box N = 12",
           "seeds": args.seeds, "load_1min_start": load0, "load_1min_end": os.getloadavg()[0],
           "cells": cells}
    text = json.dumps(doc, indent=1)
    print(text)
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write(text)


if __name__ == "__main__":
    main()

"""Arms from a URDF: robust-box for the 3-DOF horizontal arm (config/arms/arm3h), all three
joints moving; prints JSON (and writes it with --out).

Per task: plan time (the first plan in a fresh process: "cold", numba kernels loaded from their
on-disk cache; the time to load the URDF and fit its dynamics reported apart), the label
(zero-derivative / least-worst), the first-order worst per joint, the certificate (worst rest
error, per joint, per parameter, excursion), and with --check the independent re-simulation
(``ff_planner.arm.reference``: Pinocchio dynamics, DOP853) at --check fresh box points: the
largest joint error and its ratio to the certificate's. Also a baseline: the plan that only puts
the nominal rest on the goal (the start of the robust search), certified the same way. The load
average (1 min) is recorded at start and end.

Usage: nice -n 5 .venv/bin/python benchmarks/bench_urdf_arm3h.py [--budget 30] [--check 100]
       [--out benchmarks/results/urdf_arm3h.json]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--budget", type=float, default=30.0)
    ap.add_argument("--check", type=int, default=100, help="fresh box points re-simulated independently")
    ap.add_argument("--tf", type=float, default=1.5)
    ap.add_argument("--qf", default="0.5,-0.4,0.6")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    t = time.perf_counter()
    from ff_planner.arm import sim
    from ff_planner.arm.model import load_arm
    from ff_planner.arm import reference
    from ff_planner.arm.reference import reference_rest
    from ff_planner.armplan.certificate import BoxSpec, certify_arm
    from ff_planner.armplan.robust_box import plan_box_robust_arm
    t_import = time.perf_counter() - t
    t = time.perf_counter()
    arm = load_arm(REPO / "config" / "arms" / "arm3h.cell.yaml")
    t_load = time.perf_counter() - t
    q0 = np.zeros(3)
    qf = np.array([float(v) for v in args.qf.split(",")])
    t = time.perf_counter()
    res = plan_box_robust_arm(arm, q0, qf, args.tf, time_budget=args.budget, seed=args.seed)
    t_plan = time.perf_counter() - t
    worst_cert = res.certificate.worst_rest_error if res.certificate else None
    print(f"plan {t_plan:.1f} s, {res.label}, certificate {worst_cert}", file=sys.stderr, flush=True)
    out: dict = {
        "task": {"arm": "config/arms/arm3h.cell.yaml", "q0": q0.tolist(), "qf": qf.tolist(), "tf": args.tf,
                 "coast": float(res.profile.coast), "steps_per_joint": int(res.profile.n_steps),
                 "uncertain": list(res.box_names), "box": "±20 % each", "time_budget_s": args.budget},
        "import_s": t_import, "load_urdf_and_fit_s": t_load, "plan_time_cold_s": t_plan,
        "plan": res.to_dict(),
    }
    # baseline: the goal-only plan (first stage of the search), same certificate
    from scipy.optimize import least_squares

    from ff_planner.armplan.robust_box import DIFF_STEP, _start
    N = res.profile.n_steps
    x = _start(arm, q0, qf, N, args.tf, float(res.profile.coast), args.seed)
    bounds = (-np.tile(arm.i_max, N), np.tile(arm.i_max, N))

    def goal(v: np.ndarray) -> np.ndarray:
        from ff_planner.model.profile import CurrentProfile
        p = CurrentProfile.uniform(v.reshape(N, 3), args.tf, float(res.profile.coast))
        return sim.rest_position(arm, p, q0) - qf

    xb = least_squares(goal, x, bounds=bounds, diff_step=DIFF_STEP, xtol=1e-14, ftol=1e-14, gtol=1e-14).x
    from ff_planner.model.profile import CurrentProfile
    pb = CurrentProfile.uniform(xb.reshape(N, 3), args.tf, float(res.profile.coast))
    cb = certify_arm(arm, pb, q0, qf)
    out["baseline_goal_only"] = {"worst_rest_error": cb.worst_rest_error, "worst_per_joint": cb.worst_per_joint}
    if args.check > 0:
        spec = BoxSpec.of(arm)
        rows = np.random.default_rng(99_001).uniform(-1.0, 1.0, (args.check, spec.k))
        worst = np.zeros(3)
        agree = 0.0
        t = time.perf_counter()
        for i, s in enumerate(spec.scales(arm, rows)):
            ref, _ = reference_rest(arm, res.profile, q0, friction_scale=s)
            worst = np.maximum(worst, np.abs(ref - qf))
            if i < 10:
                mine = sim.rest_position(arm, res.profile, q0, friction_scale=s)
                agree = max(agree, float(np.max(np.abs(mine - ref))))
        cert = res.certificate
        assert cert is not None
        out["independent_check"] = {
            "points": args.check, "seed": 99_001,
            "simulator": f"Pinocchio CRBA/RNEA + scipy DOP853 (rtol {reference.RTOL:g})",
            "worst_per_joint": worst.tolist(), "worst": float(worst.max()),
            "ratio_to_certificate_per_joint": (worst / np.array(cert.worst_per_joint)).tolist(),
            "compiled_vs_reference_max_abs_rad_first10": agree, "seconds": time.perf_counter() - t}
    out["load_average_1min"] = {"start": load0, "end": os.getloadavg()[0]}
    text = json.dumps(out, indent=2)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()

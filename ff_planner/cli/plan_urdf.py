"""Plan a robust move for an arm from a URDF plus its cell file (docs/arms.md).

    ff-plan --cell config/arms/arm3h.cell.yaml \\
        --q0 0,0,0 --qf 0.5,-0.4,0.6 --tf 1.5 -o plan.json

    ff-plan --urdf config/arms/arm1dof.urdf --cell config/arms/arm1dof.cell.yaml \\
        --q0 0 --qf 1 --tolerance 0.15 --tf-max 2 -o plan.json

With --tolerance (rad) the planner chooses the move time: the fastest tf <= --tf-max whose
certified worst rest error (the worst joint's) meets it, searched as the 1-DOF ff-plan does; when
none does, the plan of least certified worst is written, labelled, and the exit status is 1.
Angles are the motor angles of the moving joints, base to tip (rad). The plan (currents per step
and joint, A), its label (zero-derivative / least-worst) and its certificate are written as JSON
(stdout, or -o FILE). A URDF or cell file the suite cannot use, or a request it cannot serve, is
refused with one line on stderr (exit status 2) before any planning.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Optional, Sequence


def _angles(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers (rad), got {text!r}") from None


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog="ff-plan --cell", description=__doc__.splitlines()[0])
    ap.add_argument("--cell", required=True, help="cell file (YAML): motors, friction, box, limits, held joints")
    ap.add_argument("--urdf", default=None, help="URDF file (default: the one the cell names)")
    ap.add_argument("--q0", type=_angles, required=True, help="start, rad per moving joint, e.g. 0,0,0")
    ap.add_argument("--qf", type=_angles, required=True, help="goal, rad per moving joint")
    ap.add_argument("--tf", type=float, default=None,
                    help="move time, s (default 1; with --tolerance the planner chooses it)")
    ap.add_argument("--tolerance", type=float, default=None, metavar="RAD",
                    help="certified worst rest error to meet, rad: plan the fastest tf <= --tf-max "
                         "that meets it (instead of --tf)")
    ap.add_argument("--tf-max", type=float, default=None, metavar="S",
                    help="with --tolerance: the longest move time to consider, s (default 3)")
    ap.add_argument("--coast", type=float, default=0.05, help="zero-current coast before tf, s (default 0.05)")
    ap.add_argument("--steps", type=int, default=None, help="current steps per joint (default: from the box)")
    ap.add_argument("--time-budget", type=float, default=30.0, help="planning time, s (default 30)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("-o", "--out", default=None, help="write the JSON here instead of stdout")
    args = ap.parse_args(argv)
    if args.tolerance is not None and args.tf is not None:
        ap.error("give --tf or --tolerance, not both: with --tolerance the planner chooses the move time")
    if args.tf_max is not None and args.tolerance is None:
        ap.error("--tf-max bounds a --tolerance search; give --tolerance too (or --tf)")
    from ff_planner.arm.model import load_arm
    from ff_planner.armplan.fastest import plan_fastest_arm
    from ff_planner.armplan.robust_box import plan_box_robust_arm
    from ff_planner.core.errors import ParameterError, PlanningError
    from ff_planner.optimize.fastest import DEFAULT_MOVE_TIME_MAX
    search = None
    try:
        arm = load_arm(args.cell, args.urdf)
        if args.tolerance is None:
            res = plan_box_robust_arm(arm, args.q0, args.qf, 1.0 if args.tf is None else args.tf,
                                      coast=args.coast, steps=args.steps, seed=args.seed,
                                      time_budget=args.time_budget)
            ok = res.success
        else:
            found = plan_fastest_arm(arm, args.q0, args.qf, args.tolerance,
                                     tf_max=args.tf_max or DEFAULT_MOVE_TIME_MAX, coast=args.coast,
                                     steps=args.steps, seed=args.seed, time_budget=args.time_budget)
            res, ok = found.plan, found.result.success
            search = dict(found.result.extra["tolerance_search"], met=ok,
                          message=found.result.message)
            print(f"ff-plan: {found.result.message}", file=sys.stderr)
    except (ParameterError, PlanningError) as exc:
        print(f"ff-plan: {exc}", file=sys.stderr)
        return 2
    out = dict(res.to_dict(), arm=arm.name, joints=list(arm.joints), held=list(arm.held))
    if search is not None:
        out["tolerance_search"] = search
    text = json.dumps(out, indent=2)
    if args.out:
        Path(args.out).write_text(text + "\n")
        c = res.certificate
        label = res.label if search is None or ok else "BEST-EFFORT (tolerance not met) " + res.label
        spent = res.solve_time if search is None else float(search["time_s"])
        print(f"{label} plan in {spent:.1f} s; certified worst rest error "
              f"{c.worst_rest_error if c else float('nan'):.3g} rad -> {args.out}", file=sys.stderr)
    else:
        print(text)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

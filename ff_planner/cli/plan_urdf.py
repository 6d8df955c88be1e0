"""Plan a robust move for an arm from a URDF plus its cell file (docs/arms.md).

    ff-plan --cell config/arms/arm3h.cell.yaml \\
        --q0 0,0,0 --qf 0.5,-0.4,0.6 --tf 1.5 -o plan.json

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
    ap.add_argument("--tf", type=float, default=1.0, help="move time, s (default 1)")
    ap.add_argument("--coast", type=float, default=0.05, help="zero-current coast before tf, s (default 0.05)")
    ap.add_argument("--steps", type=int, default=None, help="current steps per joint (default: from the box)")
    ap.add_argument("--time-budget", type=float, default=30.0, help="planning time, s (default 30)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("-o", "--out", default=None, help="write the JSON here instead of stdout")
    args = ap.parse_args(argv)
    from ff_planner.arm.model import load_arm
    from ff_planner.armplan.robust_box import plan_box_robust_arm
    from ff_planner.core.errors import ParameterError, PlanningError
    try:
        arm = load_arm(args.cell, args.urdf)
        res = plan_box_robust_arm(arm, args.q0, args.qf, args.tf, coast=args.coast, steps=args.steps,
                                  seed=args.seed, time_budget=args.time_budget)
    except (ParameterError, PlanningError) as exc:
        print(f"ff-plan: {exc}", file=sys.stderr)
        return 2
    out = dict(res.to_dict(), arm=arm.name, joints=list(arm.joints), held=list(arm.held))
    text = json.dumps(out, indent=2)
    if args.out:
        Path(args.out).write_text(text + "\n")
        c = res.certificate
        print(f"{res.label} plan in {res.solve_time:.1f} s; certified worst rest error "
              f"{c.worst_rest_error if c else float('nan'):.3g} rad -> {args.out}", file=sys.stderr)
    else:
        print(text)
    return 0 if res.success else 1


if __name__ == "__main__":
    sys.exit(main())

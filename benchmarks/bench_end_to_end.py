"""End-to-end final errors on the simulated stack, robust vs baselines; prints JSON.

One stack (sim driver + CAN hub on 127.0.0.1, bridge, planner, executor). For the true Coulomb
friction of the simulated arm at −20 %, 0 and +20 % of the planner's model (table 2, pc = 0.19 Nm;
set on the simulated driver at runtime), plan via the planner SERVICE and execute via the executor
ACTION: the robust motions (robust-derivative; robust-box over the planner's default ±20 % box;
uncertain pv, pc, pt), the energy-optimal and the time-optimal baselines, 0 → 1 rad in 1 s.
Reports each final error (ground truth where the arm came to rest, and the executor's figure
from the bridge's joint states), switch-time statistics and feedback rates, and the model's
exact prediction for the same profile beside it. Every run counts: each motion runs once per
friction value, no repeats.

    python benchmarks/bench_end_to_end.py [--scales 0.8,1.0,1.2] [--out FILE] [--record BAG_DIR]
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from _common import arm1dof_params, log, report

from ff_executor.bringup.demo import run_motions
from ff_executor.bringup.stack import Stack, StackOptions
from ff_executor.ros.client import StackClient
from ff_msgs_py.convert import msg_to_profile
from ff_planner.model.params import friction_scaled
from ff_planner.model.simulate import rest_position

MOTIONS = (("robust", "robust-derivative"), ("robust-box", "robust-box"),
           ("energy-optimal", "energy-optimal"), ("time-optimal", "time-optimal"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scales", default="0.8,1.0,1.2", help="true pc / model pc")
    ap.add_argument("--out", default=None)
    ap.add_argument("--record", default=None, metavar="DIR",
                    help="keep the run's bag: record its topics into this rosbag2 folder (MCAP)")
    a = ap.parse_args(argv)
    scales = [float(s) for s in a.scales.split(",")]
    model = arm1dof_params()
    rows = []
    t0 = time.monotonic()
    with Stack(StackOptions(rt_priority=10, record=a.record), log=log) as stack:   # SCHED_FIFO where permitted
        with StackClient(stack.env, "ff_bench_e2e") as client:
            for sc in scales:
                stack.set_true_params({"pc": model.pc * sc})
                log(f"true pc = {model.pc * sc:.4f} Nm ({sc:+.0%} of the model)")
                s = run_motions(client, 1.0, 1.0, MOTIONS, log=log)
                for label, m in s.items():
                    prof = msg_to_profile(m["_profile"])
                    pred = float(rest_position(friction_scaled(model, {"pc": sc}), prof, [0.0])[0] - 1.0)
                    rows.append({"true_pc_scale": sc, "true_pc_Nm": model.pc * sc, "motion": label,
                                 "objective": m["objective"], "plan_robust": m["robust"],
                                 "steps": m["steps"], "executed": m["executed"],
                                 "error_rad": m["error_truth"], "executor_error_rad": m["error"],
                                 "model_predicted_error_rad": pred,
                                 "switch_error_s": m["switch_error_s"],
                                 "switch_spread_s": m["switch_spread_s"],
                                 "missed_cycles": m["missed_cycles"], "sync_period_s": m["sync_period_s"],
                                 "setpoints_sent": m["setpoints_sent"],
                                 "feedback_messages": m["feedback_messages"],
                                 "feedback_gap_max_s": m["feedback_gap_max_s"],
                                 "feedback_rate_hz": m["feedback_rate_hz"],
                                 "plan_time_s": m["plan_time_s"]})
    table: dict[str, dict[str, float]] = {}
    for r in rows:
        table.setdefault(r["motion"], {})[f"{r['true_pc_scale'] - 1:+.0%}"] = r["error_rad"]
    out = {"benchmark": "end_to_end_final_errors", "task": "arm1dof 0 -> 1 rad in 1 s",
           "model": "table2", "final_error_rad_by_true_pc_offset": table, "rows": rows,
           "wall_s": time.monotonic() - t0}
    rob = [abs(r["error_rad"]) for r in rows if r["motion"] == "robust"]
    base = [abs(r["error_rad"]) for r in rows if r["motion"] == "energy-optimal" and r["true_pc_scale"] != 1.0]
    out["robust_max_abs_error_rad"] = float(np.max(rob))
    rbox = [abs(r["error_rad"]) for r in rows if r["motion"] == "robust-box"]
    out["robust_box_max_abs_error_rad"] = float(np.max(rbox)) if rbox else None
    out["energy_optimal_min_abs_error_off_nominal_rad"] = float(np.min(base)) if base else None
    report(out, a.out, default=float)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Deterministic execution: N consecutive runs of one robust move on the simulated stack, no repeats; JSON.

The robust 0 → 1 rad move in 1 s (robust-derivative, pv, pc, pt uncertain; planned once through the
planner SERVICE) is executed ``--runs`` times in a row (default 20) through the executor ACTION on the
simulated arm, whose true Coulomb friction is 20 % above the planner's model (the stack's
``--true-param pc=...``), at default priorities (no SCHED_FIFO, no nice). Every run counts. Per run:

- ``measured_rest``: the simulated arm's ground truth once at rest (rad);
- ``predicted_true``: the exact simulator (``ff_planner.model.simulate.rest_position``) on the SAME
  profile with the simulated arm's TRUE parameters; ``measured_minus_predicted`` (rad);
- ``predicted_nominal``: the same with the planner's nominal parameters (what the plan promises, and
  what the executor's result carries as ``predicted_position`` when the profile says);
- ``predicted_applied``: the true-friction prediction for the profile with each switch moved by its
  delay as the bridge reported it (switch timing accounted for);
- ``predicted_applied_quantised``: the same with every current as the simulated EPOS4 receives it
  (0x6071 per mille of its nominal current: 3 mA steps); what is left is the physics step and the
  frame latency after the bridge (bridge send -> simulated drive, not reported);
- switch errors (the executor's p50 / p99 / max of |applied − stamp|, and the spread max − min of
  applied − stamp over the switches), the bridge's SYNC period and the missed cycles.

``--load N`` runs N busy processes (``while True: pass``) for the whole benchmark (2 = both cores of
a 2-core machine). Summary: median / max |measured − predicted_true| and of the other differences.

    python benchmarks/bench_execution.py [--runs 20] [--load 2] [--out FILE]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from typing import Any

import numpy as np

from ff_executor.bringup.demo import plan_request
from ff_executor.bringup.identify import applied_profile
from ff_executor.bringup.stack import NOMINAL_CURRENT, Stack, StackOptions
from ff_executor.ros.client import StackClient
from ff_hwbridge.protocol.units import DriveUnits
from ff_msgs_py.convert import msg_to_profile
from ff_planner.model.params import default_params
from ff_planner.model.profile import CurrentProfile
from ff_planner.model.simulate import rest_position

PC_SCALE = 1.2          # true Coulomb friction / the model's


def busy_processes(n: int) -> list[subprocess.Popen]:
    """``n`` child processes spinning a CPU each (stopped by the caller)."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"], stdin=subprocess.DEVNULL)
            for _ in range(n)]


def stats(values: list[float]) -> dict[str, float]:
    """median / p90 / max of |values| (nan when empty)."""
    a = np.abs(np.asarray([v for v in values if np.isfinite(v)], dtype=float))
    if a.size == 0:
        return {"median": float("nan"), "p90": float("nan"), "max": float("nan"), "count": 0}
    return {"median": float(np.median(a)), "p90": float(np.percentile(a, 90)), "max": float(a.max()),
            "count": int(a.size)}


def quantised(prof: CurrentProfile) -> CurrentProfile:
    """The profile's currents as the simulated EPOS4 receives them (per mille of its nominal current)."""
    units = DriveUnits(family="epos4", nominal_current=NOMINAL_CURRENT)
    cur = np.vectorize(lambda c: units.setpoint_to_amps(units.amps_to_setpoint(float(c))))(prof.currents)
    return CurrentProfile(prof.step_times.copy(), cur, prof.tf, prof.coast)


def one_run(client: StackClient, msg: Any, nominal, true) -> dict[str, Any]:
    """Execute ``msg`` once from rest at 0 rad; the measured and predicted rest positions."""
    prof = msg_to_profile(msg)
    client.reset_arm([0.0])
    mv = client.execute(msg)
    r = mv.result
    measured = float(mv.rest_truth[0]) if mv.rest_truth is not None else float("nan")
    pred_true = float(rest_position(true, prof, [0.0])[0])
    pred_nom = float(rest_position(nominal, prof, [0.0])[0])
    applied = applied_profile(prof, mv.switch_delays)
    timed = len(mv.switch_delays) == prof.n_steps + 1 and applied is not prof
    pred_applied = float(rest_position(true, applied, [0.0])[0]) if timed else float("nan")
    pred_aq = float(rest_position(true, quantised(applied), [0.0])[0]) if timed else float("nan")
    return {
        "succeeded": mv.succeeded, "message": r.message,
        "measured_rest": measured, "executor_final_position": list(r.final_position),
        "predicted_true": pred_true, "predicted_nominal": pred_nom,
        "predicted_applied": pred_applied, "predicted_applied_quantised": pred_aq,
        "executor_predicted_position": list(r.predicted_position),
        "measured_minus_predicted": measured - pred_true,
        "measured_minus_predicted_applied": measured - pred_applied,
        "measured_minus_predicted_applied_quantised": measured - pred_aq,
        "measured_minus_nominal": measured - pred_nom,
        "switch_error_s": {"p50": r.switch_error_p50, "p99": r.switch_error_p99, "max": r.switch_error_max},
        "switch_delays_s": [float(x) for x in mv.switch_delays],
        "switch_spread_s": mv.switch_spread,
        "missed_cycles": int(r.missed_cycles), "sync_period_s": float(r.sync_period),
        "feedback_gap_max_s": mv.feedback_period_max,
    }


def main(argv: Any = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--load", type=int, default=0, help="busy processes beside the stack")
    ap.add_argument("--rt-priority", type=int, default=0,
                    help="SCHED_FIFO priority of the simulated drive and the bridge's scheduler thread "
                         "(0 = default priorities, the benchmark's condition)")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)

    def log(s: str) -> None:
        print(s, file=sys.stderr, flush=True)

    nominal = default_params("arm1dof")
    true = nominal.replace(pc=nominal.pc * PC_SCALE)
    t0 = time.monotonic()
    load = busy_processes(a.load)
    rows: list[dict[str, Any]] = []
    try:
        with Stack(StackOptions(true_params={"pc": true.pc}, rt_priority=a.rt_priority), log=log) as stack:
            with StackClient(stack.env, "ff_bench_execution") as client:
                resp = client.plan(plan_request("robust-derivative"))
                if resp.profile.n_steps == 0:
                    raise RuntimeError(f"no robust plan: {resp.message}")
                for k in range(a.runs):
                    row = one_run(client, resp.profile, nominal, true)
                    rows.append(row)
                    log(f"run {k + 1}/{a.runs}: rest {row['measured_rest']:+.6f} rad, "
                        f"measured - predicted {row['measured_minus_predicted'] * 1e3:+.2f} mrad "
                        f"(applied timing {row['measured_minus_predicted_applied'] * 1e3:+.2f}, "
                        f"+ quantised {row['measured_minus_predicted_applied_quantised'] * 1e3:+.2f}), "
                        f"switch spread {row['switch_spread_s'] * 1e6:.0f} us, "
                        f"p99 {row['switch_error_s']['p99'] * 1e6:.0f} us, missed {row['missed_cycles']}")
    finally:
        for p in load:
            p.kill()
            p.wait()
    spreads = [r["switch_spread_s"] for r in rows]
    out = {
        "benchmark": "execution_determinism", "task": "arm1dof 0 -> 1 rad in 1 s, robust-derivative",
        "true_params": {"pc": true.pc}, "pc_scale": PC_SCALE, "runs": len(rows), "repeats": 0,
        "load_processes": a.load,
        "priorities": f"SCHED_FIFO {a.rt_priority}" if a.rt_priority else "default", "cpus": os.cpu_count(),
        "loadavg_end": list(os.getloadavg()),
        "summary": {
            "abs_measured_minus_predicted_rad": stats([r["measured_minus_predicted"] for r in rows]),
            "abs_measured_minus_predicted_applied_rad": stats(
                [r["measured_minus_predicted_applied"] for r in rows]),
            "abs_measured_minus_predicted_applied_quantised_rad": stats(
                [r["measured_minus_predicted_applied_quantised"] for r in rows]),
            "abs_measured_minus_goal_rad": stats([r["measured_rest"] - 1.0 for r in rows]),
            "predicted_true_minus_goal_rad": rows[0]["predicted_true"] - 1.0 if rows else None,
            "predicted_nominal_minus_goal_rad": rows[0]["predicted_nominal"] - 1.0 if rows else None,
            "switch_spread_s": stats(spreads),
            "switch_error_p99_s": stats([r["switch_error_s"]["p99"] for r in rows]),
            "missed_cycles_total": int(sum(r["missed_cycles"] for r in rows)),
            "sync_period_s": rows[0]["sync_period_s"] if rows else None,
            "all_succeeded": all(r["succeeded"] for r in rows),
        },
        "rows": rows, "wall_s": time.monotonic() - t0,
    }
    text = json.dumps(out, indent=2, default=float)
    print(text)
    if a.out:
        with open(a.out, "w", encoding="utf-8") as fh:
            fh.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

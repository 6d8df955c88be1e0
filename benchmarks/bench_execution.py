"""Deterministic execution: N consecutive runs of one robust move on the simulated stack, no repeats; JSON.

The robust 0 → 1 rad move in 1 s (pv, pc, pt uncertain; ``--objective`` robust-box, the planner's
default, or robust-derivative, the paper's; planned once through the planner SERVICE) is executed
``--runs`` times in a row (default 20) through the executor ACTION on the simulated arm, whose true
Coulomb friction is 20 % above the planner's model (the stack's ``--true-param pc=...``), at default
priorities (no SCHED_FIFO, no nice) and the stack's default timing (setpoints latched at SYNC every
10 ms, switch times on that grid, currents on the simulated EPOS4's 3 mA grid). Every run counts.
Per run:

- ``measured_rest``: the simulated arm's ground truth once at rest (rad);
- ``predicted_true``: the exact simulator (``ff_planner.model.simulate.rest_position``) on the SAME
  profile as the planner returned it (currents already rounded to the drive's grid) with the
  simulated arm's TRUE parameters; ``measured_minus_predicted`` (rad): the issue's figure;
- ``executor_predicted_position``: the executor result's ``predicted_position`` (the profile's
  ``predicted_rest``: the model with the NOMINAL friction); ``measured_minus_executor_predicted``
  is the plan's own friction error plus everything below; ``predicted_nominal`` recomputes it here;
- ``predicted_applied``: the true-friction prediction for the profile with each switch moved by its
  delay as the bridge reported it (in SYNC mode: the SYNC instant it latched at − the stamp);
- ``predicted_applied_quantised``: the same with every current as the simulated EPOS4 receives it
  (0x6071 per mille of its nominal current: 3 mA steps); 0 difference when the planner rounded;
  ``current_grid_error_a``: the largest distance of a planned current from that grid (A);
- ``late_switches``: current changes the simulated arm applied after its plant had passed their
  instant (the sim driver's ``/diagnostics`` counter, this run's increase);
- switch errors (the executor's p50 / p99 / max of |applied − stamp|, and the spread max − min of
  applied − stamp over the switches), the bridge's SYNC period and the missed cycles.

``--load N`` runs N busy processes (``while True: pass``) for the whole benchmark (2 = both cores of
a 2-core machine). Summary: median / max |measured − predicted_true| and of the other differences;
the load averages (1, 5, 15 min) at the start, per run and at the end.

``--bridge-config FILE`` runs a robot's bridge file instead of the stack's own (e.g. the shipped
``config/bridge_epos4_1dof.yaml``: player in the bridge's process, SYNC every 10 ms from the hub's
timer as the kernel's on SocketCAN, 10 ms heartbeats, derived 130 ms timeouts), only its bus re-pointed at the hub
(``StackOptions.bridge_config_file``). A run the stack could not execute (the bridge latched,
no joint states) counts as a fault: its error is recorded, the bridge is fault-reset and the
next run goes on. ``uptime`` is recorded at the start and the end.

    python benchmarks/bench_execution.py [--runs 20] [--objective robust-box] [--load 2]
        [--player process|thread] [--bridge-config config/bridge_epos4_1dof.yaml] [--out FILE]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time
from typing import Any, Optional

import numpy as np
from _common import arm1dof_params, busy_processes, log, report, stop_processes
from diagnostic_msgs.msg import DiagnosticArray
from std_srvs.srv import Trigger

from ff_executor.bringup.demo import plan_request
from ff_executor.bringup.identify import applied_profile
from ff_executor.bringup.stack import NOMINAL_CURRENT, SYNC_PERIOD, Stack, StackOptions
from ff_executor.ros.client import StackCallError, StackClient
from ff_hwbridge.protocol.units import DriveUnits
from ff_msgs_py.convert import msg_to_profile
from ff_planner.model.profile import CurrentProfile
from ff_planner.model.simulate import rest_position

PC_SCALE = 1.2          # true Coulomb friction / the model's
OBJECTIVES = ("robust-box", "robust-derivative")
SIM_DIAG_PREFIX = "ff_sim_driver: drive"


class SimLateSwitches:
    """The sim driver's ``late_switches`` counter from ``/diagnostics`` (published at 1 Hz)."""

    def __init__(self, client: StackClient) -> None:
        self._lock = threading.Lock()
        self._latest: Optional[tuple[int, int, float]] = None   # (stamp ns, count, max µs)
        client.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for st in msg.status:
            if st.name.startswith(SIM_DIAG_PREFIX):
                v = {kv.key: kv.value for kv in st.values}
                if "late_switches" in v:
                    stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                    with self._lock:
                        self._latest = (stamp, int(v["late_switches"]),
                                        float(v.get("late_switch_max_us", "nan")))
                return

    def after(self, t_ns: int, timeout: float = 3.0) -> Optional[tuple[int, float]]:
        """(count, max µs) from the first report stamped at or after ``t_ns`` (ns, ROS clock);
        None when none came within ``timeout`` s."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self._lock:
                lt = self._latest
            if lt is not None and lt[0] >= t_ns:
                return lt[1], lt[2]
            time.sleep(0.02)
        return None


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


def grid_error(prof: CurrentProfile, quantum: float = NOMINAL_CURRENT / 1000.0) -> float:
    """Largest distance (A) of a profile current from the drive's ``quantum`` grid (A)."""
    c = np.asarray(prof.currents, float)
    return float(np.max(np.abs(c - np.round(c / quantum) * quantum))) if c.size else 0.0


def switch_grid_error(prof: CurrentProfile, grid: float = SYNC_PERIOD) -> float:
    """Largest distance (s) of a switch time from the SYNC grid (s)."""
    t = np.asarray(prof.step_times, float)
    return float(np.max(np.abs(t - np.round(t / grid) * grid))) if t.size else 0.0


def fault_reset(client: StackClient, timeout: float = 10.0) -> str:
    """Call the bridge's ``~/fault_reset`` (clears a latched safe state); its answer."""
    cli = client.node.create_client(Trigger, "/ff_hwbridge/fault_reset")
    try:
        if not cli.wait_for_service(timeout_sec=timeout):
            return "fault_reset service not available"
        res = client._wait(cli.call_async(Trigger.Request()), timeout, "fault_reset")
        return f"{'ok' if res.success else 'refused'}: {res.message}"
    finally:
        client.node.destroy_client(cli)


def failed_run(error: str) -> dict[str, Any]:
    """A run the stack could not execute (``error``): counted, with NaN figures."""
    nan = float("nan")
    return {"succeeded": False, "message": error, "error": error, "measured_rest": nan,
            "predicted_true": nan, "predicted_nominal": nan, "measured_minus_predicted": nan,
            "measured_minus_predicted_applied": nan, "measured_minus_predicted_applied_quantised": nan,
            "measured_minus_executor_predicted": nan, "quantisation_term": nan,
            "switch_timing_term": nan, "late_switches": -1, "loadavg": list(os.getloadavg()),
            "switch_error_s": {"p50": nan, "p99": nan, "max": nan}, "switch_delays_s": [],
            "switch_spread_s": nan, "missed_cycles": 0, "sync_period_s": nan,
            "applied_all_switches": False}


def one_run(client: StackClient, msg: Any, nominal, true, late: SimLateSwitches) -> dict[str, Any]:
    """Execute ``msg`` once from rest at 0 rad; the measured and predicted rest positions."""
    prof = msg_to_profile(msg)
    client.reset_arm([0.0])
    t_before = client.node.get_clock().now().nanoseconds
    late0 = late.after(t_before)
    mv = client.execute(msg)
    late1 = late.after(client.node.get_clock().now().nanoseconds)
    r = mv.result
    measured = float(mv.rest_truth[0]) if mv.rest_truth is not None else float("nan")
    pred_true = float(rest_position(true, prof, [0.0])[0])
    pred_nom = float(rest_position(nominal, prof, [0.0])[0])
    applied = applied_profile(prof, mv.switch_delays)
    timed = applied is not prof
    pred_applied = float(rest_position(true, applied, [0.0])[0]) if timed else float("nan")
    pred_aq = float(rest_position(true, quantised(applied), [0.0])[0]) if timed else float("nan")
    pred_q = float(rest_position(true, quantised(prof), [0.0])[0])
    exec_pred = [float(x) for x in r.predicted_position]
    return {
        "succeeded": mv.succeeded, "message": r.message,
        "measured_rest": measured, "executor_final_position": list(r.final_position),
        "predicted_true": pred_true, "predicted_nominal": pred_nom,
        "predicted_applied": pred_applied, "predicted_applied_quantised": pred_aq,
        "executor_predicted_position": exec_pred,
        "measured_minus_executor_predicted": measured - exec_pred[0] if exec_pred else float("nan"),
        "executor_predicted_minus_nominal": exec_pred[0] - pred_nom if exec_pred else float("nan"),
        "quantisation_term": pred_q - pred_true,
        "switch_timing_term": pred_applied - pred_true,
        "current_grid_error_a": grid_error(prof),
        "late_switches": (late1[0] - late0[0]) if late0 and late1 else -1,
        "late_switch_max_us_total": late1[1] if late1 else float("nan"),
        "loadavg": list(os.getloadavg()),
        "measured_minus_predicted": measured - pred_true,
        "measured_minus_predicted_applied": measured - pred_applied,
        "measured_minus_predicted_applied_quantised": measured - pred_aq,
        "measured_minus_nominal": measured - pred_nom,
        "switch_error_s": {"p50": r.switch_error_p50, "p99": r.switch_error_p99, "max": r.switch_error_max},
        "switch_delays_s": [float(x) for x in mv.switch_delays],
        "switch_spread_s": mv.switch_spread,
        "missed_cycles": int(r.missed_cycles), "sync_period_s": float(r.sync_period),
        "feedback_gap_max_s": mv.feedback_period_max,
        "applied_all_switches": timed,
    }


def main(argv: Any = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--load", type=int, default=0, help="busy processes beside the stack")
    ap.add_argument("--objective", choices=OBJECTIVES, default="robust-box",
                    help="robust-box (the planner's default) or robust-derivative (the paper's)")
    ap.add_argument("--rt-priority", type=int, default=0,
                    help="SCHED_FIFO priority of the simulated drive and the bridge's scheduler thread "
                         "(0 = default priorities, the benchmark's condition)")
    ap.add_argument("--player", choices=("process", "thread"), default="process",
                    help="the bridge's setpoint player in its own process (the stack's default) "
                         "or a thread of the bridge's process")
    ap.add_argument("--bridge-config", default=None, metavar="YAML",
                    help="a robot's bridge file run as shipped, its bus on the hub (e.g. "
                         "config/bridge_epos4_1dof.yaml); default: the stack's own")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    uptime_start = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()

    nominal = arm1dof_params()
    true = nominal.replace(pc=nominal.pc * PC_SCALE)
    t0 = time.monotonic()
    loadavg_start = list(os.getloadavg())
    load = busy_processes(a.load)
    rows: list[dict[str, Any]] = []
    try:
        with Stack(StackOptions(true_params={"pc": true.pc}, rt_priority=a.rt_priority,
                                player_process=a.player == "process",
                                bridge_config_file=a.bridge_config), log=log) as stack:
            with StackClient(stack.env, "ff_bench_execution") as client:
                late = SimLateSwitches(client)
                resp = client.plan(plan_request(a.objective))
                if resp.profile.n_steps == 0:
                    raise RuntimeError(f"no robust plan: {resp.message}")
                prof = msg_to_profile(resp.profile)
                planned = {"objective": a.objective, "success": bool(resp.success),
                           "robust": bool(resp.robust),
                           "step_times_s": [float(x) for x in prof.step_times],
                           "currents_a": [float(x) for x in np.ravel(prof.currents)],
                           "tf_s": float(prof.tf), "coast_s": float(prof.coast),
                           "current_grid_error_a": grid_error(prof),
                           "switch_grid_error_s": switch_grid_error(prof),
                           "predicted_rest": [float(x) for x in resp.profile.predicted_rest]}
                log(f"plan ({a.objective}): {prof.n_steps} steps, currents {planned['currents_a']} A, "
                    f"off the 3 mA grid by {planned['current_grid_error_a']:.1e} A, switches off the "
                    f"SYNC grid by {planned['switch_grid_error_s']:.1e} s")
                for k in range(a.runs):
                    try:
                        row = one_run(client, resp.profile, nominal, true, late)
                    except StackCallError as exc:     # counted: the stack could not run it
                        row = failed_run(str(exc))
                        log(f"run {k + 1}: not executed: {exc}")
                    # a missed cycle beyond the tolerance latches the bridge's safe state: the run
                    # counts as it came out, and the state is cleared so that the next run measures
                    row["fault_reset_after"] = None
                    if row["missed_cycles"] > 0 or not row["applied_all_switches"]:
                        row["fault_reset_after"] = fault_reset(client)
                        log(f"run {k + 1}: missed {row['missed_cycles']} cycle(s), "
                            f"{len(row['switch_delays_s'])} switch(es) applied: bridge fault reset "
                            f"({row['fault_reset_after']})")
                    rows.append(row)
                    log(f"run {k + 1}/{a.runs}: rest {row['measured_rest']:+.6f} rad, "
                        f"measured - predicted {row['measured_minus_predicted'] * 1e3:+.2f} mrad "
                        f"(applied timing {row['measured_minus_predicted_applied'] * 1e3:+.2f}, "
                        f"+ quantised {row['measured_minus_predicted_applied_quantised'] * 1e3:+.2f}), "
                        f"switch spread {row['switch_spread_s'] * 1e6:.0f} us, "
                        f"p99 {row['switch_error_s']['p99'] * 1e6:.0f} us, missed {row['missed_cycles']}, "
                        f"late {row['late_switches']}, load {row['loadavg'][0]:.1f}")
    finally:
        stop_processes(load)
    spreads = [r["switch_spread_s"] for r in rows]
    out = {
        "benchmark": "execution_determinism", "task": f"arm1dof 0 -> 1 rad in 1 s, {a.objective}",
        "objective": a.objective, "plan": planned,
        "bridge_config": a.bridge_config or "the simulated stack's own (StackOptions defaults)",
        "uptime_start": uptime_start,
        "uptime_end": subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip(),
        "stack": {"setpoint_timing": StackOptions().setpoint_timing, "sync_period_s": SYNC_PERIOD,
                  "current_quantum_a": NOMINAL_CURRENT / 1000.0},
        "true_params": {"pc": true.pc}, "pc_scale": PC_SCALE, "runs": len(rows), "repeats": 0,
        "load_processes": a.load,
        "priorities": f"SCHED_FIFO {a.rt_priority}" if a.rt_priority else "default",
        "player_process": a.player == "process", "cpus": os.cpu_count(),
        "loadavg_start": loadavg_start, "loadavg_end": list(os.getloadavg()),
        "summary": {
            "abs_measured_minus_predicted_rad": stats([r["measured_minus_predicted"] for r in rows]),
            "abs_measured_minus_predicted_applied_rad": stats(
                [r["measured_minus_predicted_applied"] for r in rows]),
            "abs_measured_minus_predicted_applied_quantised_rad": stats(
                [r["measured_minus_predicted_applied_quantised"] for r in rows]),
            "abs_measured_minus_executor_predicted_rad": stats(
                [r["measured_minus_executor_predicted"] for r in rows]),
            "abs_quantisation_term_rad": stats([r["quantisation_term"] for r in rows]),
            "abs_switch_timing_term_rad": stats([r["switch_timing_term"] for r in rows]),
            "runs_within_1mrad_of_predicted": int(sum(abs(r["measured_minus_predicted"]) <= 1e-3
                                                      for r in rows)),
            "late_switches_total": int(sum(max(r["late_switches"], 0) for r in rows)),
            "late_switches_unknown_runs": int(sum(r["late_switches"] < 0 for r in rows)),
            "loadavg_1min_per_run": stats([r["loadavg"][0] for r in rows]),
            "abs_measured_minus_goal_rad": stats([r["measured_rest"] - 1.0 for r in rows]),
            "predicted_true_minus_goal_rad": rows[0]["predicted_true"] - 1.0 if rows else None,
            "predicted_nominal_minus_goal_rad": rows[0]["predicted_nominal"] - 1.0 if rows else None,
            "switch_spread_s": stats(spreads),
            "switch_error_p99_s": stats([r["switch_error_s"]["p99"] for r in rows]),
            "missed_cycles_total": int(sum(r["missed_cycles"] for r in rows)),
            "runs_with_missed_cycles": int(sum(r["missed_cycles"] > 0 for r in rows)),
            "runs_not_applied": int(sum(not r["applied_all_switches"] for r in rows)),
            "fault_resets": int(sum(r["fault_reset_after"] is not None for r in rows)),
            "runs_not_executed": int(sum("error" in r for r in rows)),
            "runs_failed": int(sum(not r["succeeded"] for r in rows)),
            "sync_period_s": rows[0]["sync_period_s"] if rows else None,
            "all_succeeded": all(r["succeeded"] for r in rows),
        },
        "rows": rows, "wall_s": time.monotonic() - t0,
    }
    report(out, a.out, default=float)
    return 0


if __name__ == "__main__":
    sys.exit(main())

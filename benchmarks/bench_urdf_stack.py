"""The simulated stack with an arm from a URDF (``ff-bringup --cell config/arms/arm3h.cell.yaml``):
a move of all three joints executed --runs times on three simulated EPOS4; prints JSON (and
writes it with --out).

The plan (``--source``): ``local`` plans it in this process as ``ff-plan --cell`` does
(``plan_box_robust_arm``, six 0.2 s steps on the stack's 10 ms SYNC grid), rounds its currents to
the drives' setpoint unit (3 mA) and certifies the rounded profile; ``service`` asks the stack's
planner for ``urdf:arm3h`` (the same move time and steps; its certificate is the unrounded plan's,
the drives round what they apply). Per run: the landing (the bridge's encoders, the plant's ground
truth), its distance to the model's rest position for the profile as the drives apply it and to
the goal against the certificate per joint, missed cycles, and the simulated driver's CAN link
over the move (``~/link_stats``: the longest a frame waited between its bus time and its handling,
the longest handling, frames handled more than 0.1 s late, current changes started late on the
plant), its CPU share over the move, and the load average (1 min) before and after.

Usage: nice -n 5 .venv/bin/python benchmarks/bench_urdf_stack.py [--runs 5] [--source local]
       [--budget 10] [--out benchmarks/results/urdf_stack.json]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import log

REPO = Path(__file__).resolve().parents[1]
CELL = REPO / "config" / "arms" / "arm3h.cell.yaml"
Q0 = [0.0, 0.0, 0.0]           # rad
QF = [0.5, -0.4, 0.6]          # rad: shoulder, elbow, wrist
TF, COAST, STEPS = 1.25, 0.05, 6


def _cpu_s(pid: int) -> float:
    """CPU seconds (user + system) of process ``pid`` so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--source", choices=("local", "service"), default="local")
    ap.add_argument("--budget", type=float, default=10.0, help="planning time budget, s")
    ap.add_argument("--rt-priority", type=int, default=0,
                    help="SCHED_FIFO priority of the simulated driver and the bridge's scheduler thread (0 = off)")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()

    from std_srvs.srv import Trigger

    from ff_executor.bringup.stack import NOMINAL_CURRENT, Stack, StackOptions
    from ff_executor.ros.client import StackClient
    from ff_msgs_py.convert import certificate_from_msg, msg_to_profile, profile_to_msg
    from ff_msgs.srv import PlanTrajectory
    from ff_planner.arm.model import load_arm
    from ff_planner.arm.sim import simulate
    from ff_planner.armplan.certificate import certify_arm
    from ff_planner.armplan.robust_box import plan_box_robust_arm
    from ff_planner.optimize.quantize import quantize_profile

    load0 = os.getloadavg()[0]
    arm = load_arm(CELL)
    quantum = NOMINAL_CURRENT / 1000.0
    plan: dict = {"source": a.source}
    if a.source == "local":
        t0 = time.monotonic()
        res = plan_box_robust_arm(arm, Q0, QF, TF, coast=COAST, steps=STEPS, time_budget=a.budget, certify=False)
        applied = quantize_profile(res.profile, quantum, arm.i_max.tolist())
        cert = certify_arm(arm, applied, np.asarray(Q0), np.asarray(QF))
        plan.update(label=res.label, plan_and_certificate_s=time.monotonic() - t0)
    run_dir = Path(tempfile.mkdtemp(prefix="bench-urdf-stack-"))
    # the planner's warm-up plans the built-in arms (their JIT caches), not needed for urdf:NAME
    opts = StackOptions(cell=str(CELL), planner=a.source == "service", run_dir=str(run_dir),
                        planner_overrides={"warmup": False}, start_timeout=180.0, rt_priority=a.rt_priority)
    t0 = time.monotonic()
    runs = []
    with Stack(opts, log=log) as stack:
        up_s = time.monotonic() - t0
        client = StackClient(stack.env, name="bench_urdf_stack")
        stats = client.node.create_client(Trigger, "/ff_sim_driver/link_stats")
        assert stats.wait_for_service(timeout_sec=10.0)
        sim_pid = next(p.pid for p in stack.procs if p.name == "ff_sim_driver")
        try:
            if a.source == "service":
                t1 = time.monotonic()
                resp = client.plan(PlanTrajectory.Request(model=f"urdf:{arm.name}", q0=Q0, qf=QF, move_time=TF,
                                                          steps=STEPS, time_budget=a.budget),
                                   timeout=a.budget + 120.0)
                if resp.profile.n_steps == 0:
                    raise SystemExit(f"the planner found no plan: {resp.message}")
                applied = quantize_profile(msg_to_profile(resp.profile), quantum, arm.i_max.tolist())
                cert = certificate_from_msg(resp.certificate)
                plan.update(label="planner service", message=resp.message, plan_s=time.monotonic() - t1)
            assert cert is not None
            worst = np.asarray(cert.worst_per_joint)
            model_rest = simulate(arm, applied, Q0).q_rest
            msg = profile_to_msg(applied, f"urdf:{arm.name}", Q0, QF, list(arm.joints),
                                 predicted_rest=model_rest.tolist())
            plan.update(certificate_per_joint=worst.tolist(), model_rest=model_rest.tolist())
            for k in range(a.runs):
                client.reset_arm(Q0)
                client._wait(stats.call_async(Trigger.Request()), 10.0, "link stats")
                la = os.getloadavg()[0]
                c0, w0 = _cpu_s(sim_pid), time.monotonic()
                out = client.execute(msg, timeout=60.0)
                cpu = (_cpu_s(sim_pid) - c0) / (time.monotonic() - w0)
                link = json.loads(client._wait(stats.call_async(Trigger.Request()), 10.0, "link stats").message)
                r = out.result
                final = np.asarray(r.final_position, float)
                if final.shape != (3,):          # no landing (the move was aborted: its message says why)
                    final = np.full(3, np.nan)
                truth = out.rest_truth
                drives = link["drives"].values()
                row = {
                    "run": k + 1, "succeeded": bool(r.success), "message": r.message,
                    "missed_cycles": int(r.missed_cycles), "landing": final.tolist(),
                    "truth": None if truth is None else truth.tolist(),
                    "error_to_model_rad": (final - model_rest).tolist(),
                    "truth_error_to_model_rad": (None if truth is None or len(truth) != 3
                                                 else (truth - model_rest).tolist()),
                    "error_to_goal_rad": (final - np.asarray(QF)).tolist(),
                    "within_certificate": bool(r.success and np.all(np.abs(final - np.asarray(QF)) <= worst)),
                    "frame_wait_max_ms": max(d["rx_lag_max_us"] for d in drives) / 1e3,
                    "frame_handling_max_ms": max(d["handle_max_us"] for d in drives) / 1e3,
                    "frames": sum(d["rx_frames"] for d in drives),
                    "frames_late_100ms": sum(d["rx_late"] for d in drives),
                    "late_switches": link["late_switches"], "sim_driver_cpu_share": cpu,
                    "load_1min": [la, os.getloadavg()[0]]}
                runs.append(row)
                log(f"run {k + 1}: {'ok' if row['succeeded'] else 'FAILED'}, landing - model "
                    f"{np.round(np.asarray(row['error_to_model_rad']) * 1e6, 1).tolist()} urad, within certificate "
                    f"{row['within_certificate']}, frames waited <= {row['frame_wait_max_ms']:.1f} ms, handled in "
                    f"<= {row['frame_handling_max_ms']:.1f} ms, sim driver {cpu * 100:.0f} % of a core, load {la:.1f}")
        finally:
            client.node.destroy_client(stats)
            client.close()
    report = {"bench": "urdf_stack", "rt_priority": a.rt_priority, "arm": arm.name, "joints": list(arm.joints),
              "q0": Q0, "qf": QF,
              "tf": TF, "steps": STEPS, "plan": plan, "stack_up_s": up_s, "runs": runs,
              "all_within_certificate": all(r["within_certificate"] and r["succeeded"] for r in runs),
              "frame_wait_max_ms": max(r["frame_wait_max_ms"] for r in runs),
              "frame_handling_max_ms": max(r["frame_handling_max_ms"] for r in runs),
              "load_1min_start": load0, "load_1min_end": os.getloadavg()[0]}
    text = json.dumps(report, indent=1)
    print(text)
    if a.out:
        Path(a.out).write_text(text + "\n")
    return 0 if report["all_within_certificate"] else 1


if __name__ == "__main__":
    sys.exit(main())

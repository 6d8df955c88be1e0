"""Planner service latency, measured by a client in another process than the ff_planner node.

Prints JSON:
- cold: 1-DOF k = 3 (pv, pc, pt) robust plans on distinct tasks, motion library off: p50/p95 (s)
  (goal p50 <= 0.1 s);
- warm: the same tasks again with the library filled: exact library hits, shifted copies, and
  re-optimisation from the nearest stored neighbour (no multistart): p50/p95 each (goal <= 0.01 s);
- concurrent: 50 requests sent at once: answered, refused cleanly (TIME_BUDGET_EXHAUSTED,
  "overloaded"), unanswered.
Latency = client send -> response received (ROS service round trip included).

Usage: python benchmarks/bench_planner_service.py [--n 30] [--starts 50] [--workers 2]
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

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ff_msgs_py.launch import apply_ros_environment, ros_environment, start_module, wait_for_line  # noqa: E402


def _node(env, folder: Path, name: str, **params) -> object:
    lines = "\n".join(f"    {k}: {json.dumps(v)}" for k, v in params.items())
    path = folder / f"{name}.yaml"
    path.write_text(f"ff_planner:\n  ros__parameters:\n{lines}\n")
    proc = start_module(name, "ff_planner.ros.planner_node", ["--ros-args", "--params-file", str(path)], env,
                        log_dir=str(folder))
    if not wait_for_line(proc, "ff_planner ready", 300):
        proc.stop()
        raise SystemExit(f"planner node did not start:\n{proc.output()[-3000:]}")
    return proc


def _quant(xs) -> dict:
    a = np.asarray(xs, float)
    if a.size == 0:
        return {"n": 0}
    return {"n": int(a.size), "p50_s": float(np.percentile(a, 50)), "p95_s": float(np.percentile(a, 95)),
            "min_s": float(a.min()), "max_s": float(a.max())}


class Client:
    def __init__(self, ctx_node, cli):
        from rclpy.executors import SingleThreadedExecutor

        self.node, self.cli = ctx_node, cli
        self.ex = SingleThreadedExecutor(context=ctx_node.context)
        self.ex.add_node(ctx_node)

    def many(self, reqs, timeout=120.0):
        """Send all at once; returns [(latency s or None, response or None)]."""
        t0 = {}
        done = {}
        futs = []
        for i, r in enumerate(reqs):
            t0[i] = time.perf_counter()
            f = self.cli.call_async(r)
            f.add_done_callback(lambda _f, i=i: done.__setitem__(i, time.perf_counter()))
            futs.append(f)
        end = time.monotonic() + timeout
        while len(done) < len(futs) and time.monotonic() < end:
            self.ex.spin_once(timeout_sec=0.01)
        return [((done[i] - t0[i]) if i in done else None, f.result() if f.done() else None)
                for i, f in enumerate(futs)]

    def one(self, req, timeout=120.0):
        return self.many([req], timeout)[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=30, help="tasks per latency figure")
    ap.add_argument("--starts", type=int, default=50)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--budget", type=float, default=20.0, help="s, time budget per request")
    ap.add_argument("--objective", default="robust-derivative")
    args = ap.parse_args()

    env = ros_environment()
    apply_ros_environment(env)
    folder = Path(tempfile.mkdtemp(prefix="ff-bench-planner-"))

    import rclpy
    from rclpy.node import Node
    from rclpy.qos import QoSProfile

    from ff_msgs.srv import PlanTrajectory

    def req(qf, q0=0.0, tf=1.0, seed=0):
        return PlanTrajectory.Request(model="arm1dof", q0=[q0], qf=[qf], move_time=tf,
                                      uncertain=["pv", "pc", "pt"], objective=args.objective,
                                      starts=args.starts, seed=seed, time_budget=args.budget)

    rng = np.random.default_rng(1)
    goals = np.round(rng.uniform(0.6, 1.4, args.n), 4)
    out: dict = {"benchmark": "planner_service", "machine": platform.machine(), "cpus": os.cpu_count(),
                 "python": platform.python_version(), "task": "arm1dof table2, k=3 (pv,pc,pt), N=5, tf=1 s",
                 "starts": args.starts, "workers": args.workers, "objective": args.objective}
    rclpy.init()
    node = Node("bench_planner_client")
    cli = node.create_client(PlanTrajectory, "/ff_planner/plan", qos_profile=QoSProfile(depth=200))
    client = Client(node, cli)
    procs = []
    try:
        # --- cold: library off -------------------------------------------------------------
        proc = _node(env, folder, "cold", use_library=False, workers=args.workers, max_pending=16)
        procs.append(proc)
        assert cli.wait_for_service(timeout_sec=30)
        client.one(req(1.0))                                   # first call: discovery, caches
        cold = [client.one(req(float(g))) for g in goals]
        out["cold"] = _quant([t for t, r in cold if r is not None and r.success])
        out["cold"]["robust"] = sum(bool(r and r.success and r.robust) for _, r in cold)
        out["cold"]["no_plan"] = sum(bool(r and not r.success) for _, r in cold)
        failed = {r.message[:120] for _, r in cold if r is not None and not r.success}
        out["cold"]["failed_examples"] = sorted(failed)[:3]
        out["cold"]["planner_solve_time_p50_s"] = float(np.median([r.solve_time for _, r in cold if r]))
        out["cold"]["goal_p50_s"] = 0.1

        # --- concurrency: 50 at once, cold tasks, small queue -------------------------------
        conc_goals = np.round(rng.uniform(0.5, 1.5, 50), 5)
        burst = client.many([req(float(g), seed=i) for i, g in enumerate(conc_goals)], timeout=180)
        refused = [r for _, r in burst if r is not None and not r.success
                   and r.error_code == PlanTrajectory.Response.TIME_BUDGET_EXHAUSTED]
        out["concurrent"] = {
            "sent": 50, "answered": sum(r is not None for _, r in burst),
            "succeeded": sum(bool(r and r.success) for _, r in burst),
            "refused_overloaded": sum("overloaded" in r.message for r in refused),
            "refused_time_budget": sum("overloaded" not in r.message for r in refused),
            "other_failures": sorted({r.message[:100] for _, r in burst if r is not None and not r.success
                                      and r.error_code != PlanTrajectory.Response.TIME_BUDGET_EXHAUSTED}),
            "unanswered": sum(r is None for _, r in burst),
            "wall_s": max(t for t, r in burst if t is not None), "max_pending": 16}
        proc.stop()
        procs.remove(proc)

        # --- warm: library on ----------------------------------------------------------------
        lib = folder / "motions.sqlite"
        proc = _node(env, folder, "warm", library_path=str(lib), workers=args.workers, max_pending=16,
                     warm_max_distance=0.5)
        procs.append(proc)
        for _ in range(100):                                  # wait for the new server
            if cli.service_is_ready():
                break
            time.sleep(0.1)
        fill = [client.one(req(float(g))) for g in goals]      # cold, stored
        out["warm_fill_solved"] = sum(bool(r and r.success) for _, r in fill)
        hits = [client.one(req(float(g))) for g in goals]       # same tasks: library hits
        shifts = [client.one(req(float(g) + 0.75, q0=0.75)) for g in goals]   # shifted copies
        near = [client.one(req(float(g) + 0.013)) for g in goals]             # nearest neighbour
        def kind(rs, prefix):   # the node's message says how a warm answer came about
            return [t for t, r in rs if r is not None and r.success and r.warm_start
                    and r.message.startswith(prefix)]

        out["warm_hit"] = _quant(kind(hits, "from the motion library (library entry"))
        out["warm_shift"] = _quant(kind(shifts, "from the motion library (shifted copy"))
        out["warm_reoptimised"] = _quant(kind(near, "warm start from library entry"))
        out["warm_reoptimised"]["answered_warm"] = sum(bool(r and r.warm_start) for _, r in near)
        out["warm_reoptimised"]["succeeded"] = sum(bool(r and r.success) for _, r in near)
        out["warm_reoptimised"]["robust"] = sum(bool(r and r.success and r.robust) for _, r in near)
        out["warm_reoptimised"]["messages"] = sorted({r.message[:100] for _, r in near if r and not r.warm_start})[:3]
        out["warm_goal_s"] = 0.01
        out["round_trip_floor"] = _quant([t for t, r in (client.one(PlanTrajectory.Request(model="nope"))
                                                         for _ in range(20)) if r is not None])
    finally:
        for p in procs:
            p.stop()
        node.destroy_node()
        rclpy.shutdown()
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()

"""Benchmark of the 1-DOF robust planner (issues 3 and 10); prints one JSON document.

Measured in one run, same tasks and seeds:
- ours: ``plan_robust_1dof`` for k = 3 (N = 5) and k = 1 (N = 3, each of pv, pc, pt), 0 → 1 rad
  in 1 s, over --seeds seeds: wall time to a verified truly robust plan (median, p90), the
  compiled part alone (search and the in-call verification, ``search_time_s``), time per start,
  success rate per start;
- warm starts (motion-library continuation): from a solved neighbour (goal ±0.1/0.25 rad,
  tf +0.1 s) its own currents alone, and with 15 perturbed copies in one ``warm_only`` call;
- first plan in a fresh process (numba cache warm) and in a fresh install (empty numba cache:
  cold compilation), each as a subprocess;
- peer: a straightforward scipy SLSQP implementation of the paper's method (minimise the sum of
  |0.1 % forward-difference sensitivities| of q(tf) and q̇(tf) subject to q(tf) = qf,
  q̇(tf) = 0, |I| ≤ i_max; SLSQP's own finite-difference gradients; the same compiled
  simulator), multistart from the same seeded starts until a start yields a plan that passes the
  same true-derivative verification, capped per seed.

With ``--certificate`` only: the facade's answer (search, verification, rest position and the
box certificate) per seed, median of 5 calls, beside the certificate alone and the search alone;
the same for robust-box N = 12 (one call per seed).

Usage: python benchmarks/bench_planner_1dof.py [--seeds 30] [--peer-seeds 5] [--peer-cap 20]
       python benchmarks/bench_planner_1dof.py --certificate [--seeds 20]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np


def _stats(xs):
    xs = np.asarray(xs, float)
    if xs.size == 0:
        return None
    return {"median": float(np.median(xs)), "p90": float(np.percentile(xs, 90)),
            "min": float(xs.min()), "max": float(xs.max()), "n": int(xs.size)}


def bench_ours(seeds, uncertain, starts=5000):
    from ff_planner.model.profile import PlanRequest
    from ff_planner.optimize.robust1d import plan_robust_1dof

    total, search, tried, ok = [], [], 0, 0
    per_start, cpu = [], []
    for seed in seeds:
        req = PlanRequest(objective="robust-derivative",
                          uncertain=tuple(uncertain), starts=starts, seed=seed, time_budget=30.0)
        t0 = time.perf_counter()
        c0 = time.process_time()
        r = plan_robust_1dof(req)
        dt = time.perf_counter() - t0
        cpu.append(time.process_time() - c0)
        total.append(dt)
        search.append(r.extra["search_time_s"])
        tried += r.starts_tried
        per_start.append(r.extra["search_time_s"] / max(1, r.starts_tried))
        ok += int(r.success and r.robust)
    return {"uncertain": list(uncertain), "seeds": len(seeds), "robust_plans": ok,
            "time_to_robust_plan_s": _stats(total), "search_time_s": _stats(search),
            "cpu_time_to_robust_plan_s": _stats(cpu),
            "time_per_start_s": float(sum(search) / max(1, tried)),
            "starts_per_plan_mean": tried / len(seeds)}


def bench_warm(uncertain, sigma=0.3, copies=15):
    """Continuation from solved neighbours: how often the neighbour's own currents converge,
    how often one warm_only call with them and ``copies`` perturbed copies (σ·√j A) does."""
    import math

    from ff_planner.model.profile import PlanRequest
    from ff_planner.optimize.robust1d import plan_robust_1dof

    own = anyof = tasks = 0
    times, tried = [], []
    for g in np.arange(0.5, 2.01, 0.25):
        for tf in (0.9, 1.0, 1.1):
            base = plan_robust_1dof(PlanRequest(objective="robust-derivative",
                                                qf=(g,), tf=tf, uncertain=tuple(uncertain),
                                                starts=2000, seed=1))
            if not base.success:
                continue
            I0 = base.profile.currents[:, 0]
            for dg, dtf in ((0.1, 0.0), (0.25, 0.0), (0.0, 0.1), (-0.25, 0.0), (0.25, 0.1)):
                req = PlanRequest(objective="robust-derivative", qf=(g + dg,), tf=tf + dtf,
                                  uncertain=tuple(uncertain), starts=copies + 1, seed=1)
                rng = np.random.default_rng(1)
                block = [I0] + [np.clip(I0 + rng.normal(0.0, sigma * math.sqrt(j), I0.shape),
                                        -10.0, 10.0) for j in range(1, copies + 1)]
                t0 = time.perf_counter()
                r = plan_robust_1dof(req, initial_currents=np.array(block), warm_only=True)
                times.append(time.perf_counter() - t0)
                tasks += 1
                anyof += int(r.success)
                own += int(r.success and r.starts_tried == 1)
                if r.success:
                    tried.append(r.starts_tried)
    return {"uncertain": list(uncertain), "tasks": tasks, "neighbour_currents_converge": own,
            f"neighbour_or_{copies}_perturbed_converge": anyof,
            "starts_per_success_mean": float(np.mean(tried)) if tried else None,
            "time_per_call_s": _stats(times)}


def peer_plan(seed, uncertain, n, cap, starts=5000):
    """The paper's method with scipy SLSQP and finite differences (see module docstring)."""
    from scipy.optimize import minimize

    from ff_planner.model.arm1dof import final_state
    from ff_planner.model.params import preset
    from ff_planner.model.profile import CurrentProfile
    from ff_planner.optimize.robust1d import verify

    p = preset("table2")
    tf, coast, goal = 1.0, 0.05, 1.0
    rng = np.random.default_rng(seed)
    X0 = rng.uniform(-p.i_max, p.i_max, (starts, n))
    perturbed = [p.replace(**{k: getattr(p, k) * 1.001}) for k in uncertain]
    h = [getattr(p, k) * 1e-3 for k in uncertain]

    def sim(I, par=p):
        return final_state(par, CurrentProfile.uniform(I, tf, coast), 0.0)

    def objective(I):
        q, v = sim(I)
        s = 0.0
        for par, hk in zip(perturbed, h):
            qp, vp = sim(I, par)
            s += abs((qp - q) / hk) + abs((vp - v) / hk)
        return s

    cons = [{"type": "eq", "fun": lambda I: np.array(sim(I)) - np.array([goal, 0.0])}]
    t0 = time.perf_counter()
    best = None       # least true max |dq/dp| among the peer's plans that reach the goal at rest
    for s in range(starts):
        if time.perf_counter() - t0 > cap:
            return {"found": False, "time_s": time.perf_counter() - t0, "starts": s,
                    "best_true_max_abs_derivative": best}
        res = minimize(objective, X0[s], method="SLSQP", constraints=cons,
                       bounds=[(-p.i_max, p.i_max)] * n,
                       options={"maxiter": 200, "ftol": 1e-6})
        prof = CurrentProfile.uniform(res.x, tf, coast)
        ver = verify(p, prof, 0.0, goal, list(uncertain))
        if ver["robust"]:
            return {"found": True, "time_s": time.perf_counter() - t0, "starts": s + 1,
                    "best_true_max_abs_derivative": ver["max_abs_derivative"]}
        if abs(ver["q_tf"] - goal) < 1e-4 and abs(ver["qd_tf"]) < 1e-4:
            m = ver["max_abs_derivative"]
            best = m if best is None else min(best, m)
    return {"found": False, "time_s": time.perf_counter() - t0, "starts": starts,
            "best_true_max_abs_derivative": best}


def bench_peer(seeds, uncertain, n, cap):
    runs = [peer_plan(s, uncertain, n, cap) for s in seeds]
    found = [r["time_s"] for r in runs if r["found"]]
    spent = sum(r["time_s"] for r in runs)
    starts = sum(r["starts"] for r in runs)
    bests = [r["best_true_max_abs_derivative"] for r in runs
             if r["best_true_max_abs_derivative"] is not None]
    return {"uncertain": list(uncertain), "seeds": len(seeds), "robust_plans": len(found),
            "time_to_robust_plan_s": _stats(found), "time_spent_s": spent,
            "best_true_max_abs_derivative_near_goal_at_rest": min(bests) if bests else None,
            "time_per_start_s": spent / max(1, starts), "cap_per_seed_s": cap}


FIRST_PLAN = ("import time; t0 = time.perf_counter(); "
              "from ff_planner.model.profile import PlanRequest; "
              "from ff_planner.optimize.robust1d import plan_robust_1dof; "
              "t1 = time.perf_counter(); "
              "r = plan_robust_1dof(PlanRequest(objective='robust-derivative', starts=5000, seed=0)); "
              "t2 = time.perf_counter(); "
              "import json; print(json.dumps({'import_s': t1 - t0, 'first_plan_s': t2 - t1, "
              "'robust': bool(r.robust)}))")


def first_plan(cache_dir=None):
    env = dict(os.environ)
    if cache_dir is not None:
        env["NUMBA_CACHE_DIR"] = cache_dir
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", FIRST_PLAN], env=env, capture_output=True,
                         text=True, timeout=600)
    wall = time.perf_counter() - t0
    if out.returncode != 0:
        return {"error": out.stderr[-500:]}
    d = json.loads(out.stdout.strip().splitlines()[-1])
    d["process_wall_s"] = wall
    return d


def bench_with_certificate(seeds, objective="robust-derivative", repeats=5):
    """The facade's answer (search, verification, rest position, box certificate) per seed:
    median over ``repeats`` calls of the wall time, and the certificate alone
    (``certify_1dof`` of the same plan), in-process, kernels loaded."""
    from ff_planner.model.profile import PlanRequest
    from ff_planner.optimize.certificate import certify_1dof
    from ff_planner.optimize.planner import plan

    total, cert, search, cpu = [], [], [], []
    for seed in seeds:
        req = PlanRequest(objective=objective, seed=seed,
                          starts=5000 if objective == "robust-derivative" else 50,
                          steps=None if objective == "robust-derivative" else 12)
        per, per_c, per_cpu = [], [], []
        for _ in range(repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            r = plan(req)
            per.append(time.perf_counter() - t0)
            per_cpu.append(time.process_time() - c0)
            t0 = time.perf_counter()
            certify_1dof(r.params, r.profile, float(r.q0[0]), float(r.qf[0]),
                         list(req.uncertain), req.box)
            per_c.append(time.perf_counter() - t0)
        total.append(float(np.median(per)))
        cpu.append(float(np.median(per_cpu)))
        cert.append(float(np.median(per_c)))
        search.append(float(r.extra["search_time_s"]))
    return {"objective": objective, "seeds": len(seeds), "repeats_per_seed": repeats,
            "plan_with_certificate_wall_s": _stats(total), "plan_with_certificate_cpu_s":
            _stats(cpu), "certificate_alone_s": _stats(cert), "search_s": _stats(search)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=30)
    ap.add_argument("--peer-seeds", type=int, default=5)
    ap.add_argument("--peer-cap", type=float, default=20.0, help="s per seed for the peer")
    ap.add_argument("--no-fresh", action="store_true", help="skip the fresh-process runs")
    ap.add_argument("--certificate", action="store_true",
                    help="only: plan + certificate through the facade (robust-derivative, and "
                         "robust-box N = 12), seeds 0..seeds-1")
    a = ap.parse_args()
    seeds = list(range(a.seeds))
    from ff_planner.model.profile import PlanRequest
    from ff_planner.optimize.robust1d import plan_robust_1dof

    plan_robust_1dof(PlanRequest(objective="robust-derivative", starts=5000,
                                 seed=12345))    # load the compiled code
    if a.certificate:
        from ff_planner.optimize.planner import plan

        plan(PlanRequest(objective="robust-derivative", seed=1))
        plan(PlanRequest(steps=12, seed=1))
        res = {"load_average_at_start": os.getloadavg(),
               "robust_derivative": bench_with_certificate(seeds),
               "robust_box_N12": bench_with_certificate(seeds, "robust-box", repeats=1),
               "load_average_at_end": os.getloadavg()}
        print(json.dumps(res, indent=1))
        return
    out: dict = {"task": "arm1dof table2, 0 -> 1 rad, tf = 1 s, coast 0.05 s",
                 "machine_cores": os.cpu_count(), "load_average_at_start": os.getloadavg()}
    out["ours_k3_N5"] = bench_ours(seeds, ("pv", "pc", "pt"))
    out["ours_k1_N3"] = {k: bench_ours(seeds, (k,)) for k in ("pv", "pc", "pt")}
    out["warm_k1_pc"] = bench_warm(("pc",))
    out["warm_k3"] = bench_warm(("pv", "pc", "pt"))
    pseeds = seeds[:a.peer_seeds]
    out["peer_slsqp_fd_k3_N5"] = bench_peer(pseeds, ("pv", "pc", "pt"), 5, a.peer_cap)
    out["peer_slsqp_fd_k1_N3_pc"] = bench_peer(pseeds, ("pc",), 3, a.peer_cap)
    ours3 = bench_ours(pseeds, ("pv", "pc", "pt"))
    ours1 = bench_ours(pseeds, ("pc",))
    p3, p1 = out["peer_slsqp_fd_k3_N5"], out["peer_slsqp_fd_k1_N3_pc"]
    out["ratio_peer_over_ours"] = {
        "k3_same_seeds_time_per_start": p3["time_per_start_s"] / ours3["time_per_start_s"],
        "k3_same_seeds_time_spent_over_ours": p3["time_spent_s"] / sum(
            [ours3["time_to_robust_plan_s"]["median"] * len(pseeds)]),
        "k1_pc_same_seeds_median": (p1["time_to_robust_plan_s"]["median"]
                                    / ours1["time_to_robust_plan_s"]["median"]
                                    if p1["time_to_robust_plan_s"] else None),
        "note": "where the peer found no robust plan within its cap, time_spent is a lower bound",
    }
    if not a.no_fresh:
        with tempfile.TemporaryDirectory() as d:
            out["fresh_install_first_plan"] = first_plan(d)     # empty cache: cold compile
            out["fresh_process_first_plan_cache_warm_dir"] = first_plan(d)
        out["fresh_process_first_plan"] = first_plan()
    out["load_average_at_end"] = os.getloadavg()
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()

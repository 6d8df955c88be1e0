"""Benchmark of friction identification (ff_planner.identify, ``ff-identify``); prints one JSON document.

For --trials arms with true pv, pc, pt drawn uniformly within ±30 % of table 2 (seeded), the
default excitation (4 levels × 2 directions inside q ∈ [−1, 1] rad, |q̇| ≤ 3 rad/s, designed from
the table-2 guess with a ±50 % prior box) is measured with the simulated sensors
(``ff_planner.identify.measure``: 4096-count encoder behind the 1:54 gear, 1 kHz; current noise
0.02 A + 2 % ripple) and fitted. Reported per parameter: relative error (median, p95, max), the
fraction of 95 % intervals that contain the truth, the median interval half-width; the fraction
of fits judged adequate, fit wall time, and the seconds of arm motion (profile time) used.
``--fit-inertia`` fits J too (true J drawn within ±10 % of 0.17 kg·m²). ``--stack N`` also runs
N trials on ONE simulated ROS stack (``ff_executor.bringup.identify.identification_options``:
setpoints latched at SYNC, timing from the CAN bus; the arm's true friction set at runtime per
trial, the arm put back at 0 rad): an excitation whose envelope holds with a switch 20 ms late
(≤ 3 A, 18.8 s of motion); per trial the truth, estimates, errors, 95 % intervals, adequacy,
stack faults and the simulated arm's late current changes, the same runs fitted with the bridge's
joint states placed by their stamps instead of the drive's answers read off the bus
("bridge_stamps", for comparison), the count of fits that called these true-Eq. 9 arms a
mismatch ("false_mismatch"), and the same "checks" (a trial the stack could not complete is
listed under "failed" with its one-line reason and counts against the coverage check);
``--stack-mismatch N`` N more trials per kind of friction that is not Eq. 9 on the stack's arm
(``friction.*`` of the sim driver), slow (~32 s a trial). ``--stack-plan N``:
identify once on a stack with the planner (true friction pv −15 %, pc +20 %, pt −15 % of
table 2), plan robust-box over the identified box and execute it N times: how many landed within
the certificate (+ the switch timing the bus showed; ``ff_executor.bringup.loop``).

``--mismatch N``: N arms per kind of friction that is not Eq. 9 (a Stribeck rise of 30 % of pc
below 0.1 rad/s; a Coulomb level varying ±10 % with position, period 0.25 rad), same draw, same
excitation: the rate at which the fit flags the mismatch, and how often its (widened) intervals
hold the arm's sliding friction. ``--learn N``: learning from use (``ff_planner.identify.learn``)
on N arms drawn from a prior of pv ±30 %, pc and pt ±5 % (95 %) around table 2: the update from
the rest positions of 5 baseline motions (energy- and time-optimal, planned on the prior) and,
separately, of 3 robust motions: errors, coverage and information (bits) per execution.
``--issue`` = ``--trials 20 --mismatch 20 --learn 20`` plus a "checks" section: pc and pt within
3 %, pv within 10 %, at most 60 s of motion, 95 % intervals holding the truth in >= 18 of 20.

Usage: python benchmarks/bench_identify.py [--trials 50] [--seed 0] [--fit-inertia] [--stack 0]
       [--stack-mismatch 0] [--stack-seed S] [--stack-plan 0] [--mismatch 0] [--learn 0] [--issue]
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from ff_planner.identify import Envelope, design_excitation, fit_friction
from ff_planner.identify.learn import Execution, prior_from_box, update_from_executions
from ff_planner.identify.measure import FrictionMismatch, Sensors, measure_rest, measure_runs
from ff_planner.model.params import Arm1DofParams, preset
from ff_planner.model.profile import PlanRequest
from ff_planner.optimize import plan

KEYS = ("pv", "pc", "pt")


def _stats(xs):
    xs = np.abs(np.asarray(xs, float))
    return {"median": float(np.median(xs)), "p95": float(np.percentile(xs, 95)), "max": float(xs.max()),
            "n": int(xs.size)}


def _draw(rng, base, fit_inertia):
    f = 1.0 + rng.uniform(-0.3, 0.3, 3)
    vals = {k: float(getattr(base, k)) * x for k, x in zip(KEYS, f)}
    if fit_inertia:
        vals["J"] = float(base.J) * (1.0 + rng.uniform(-0.1, 0.1))
    return base.replace(**vals)


def _summarise(rows, keys):
    out = {"trials": len(rows), "adequate_fraction": float(np.mean([r["adequate"] for r in rows]))}
    for k in keys:
        out[k] = {"rel_error": _stats([r["err"][k] for r in rows]),
                  "coverage95": float(np.mean([r["cover"][k] for r in rows])),
                  "half_width_rel_median": float(np.median([r["half"][k] for r in rows]))}
    out["fit_wall_s"] = _stats([r["fit_s"] for r in rows])
    out["motion_s"] = float(np.median([r["motion_s"] for r in rows]))
    return out


def _row(fit, true, keys, fit_s):
    return {"adequate": fit.adequate, "fit_s": fit_s, "motion_s": fit.motion_seconds,
            "err": {k: fit.estimates[k] / getattr(true, k) - 1.0 for k in keys},
            "cover": {k: fit.interval95[k][0] <= getattr(true, k) <= fit.interval95[k][1] for k in keys},
            "half": {k: fit.half_width(k) / abs(fit.estimates[k]) for k in keys}}


MISMATCHES = {"stribeck": FrictionMismatch(stribeck=0.3, stribeck_speed=0.1),
              "position_coulomb": FrictionMismatch(coulomb_ripple=0.1, coulomb_period=0.25)}


def _mismatch(rng, base, ex, n):
    """Flag rate and coverage of the sliding (Eq. 9 part of the) friction per mismatch kind."""
    out = {}
    for name, mm in MISMATCHES.items():
        rows = []
        for _ in range(n):
            true = _draw(rng, base, False)
            recs = measure_runs(true, ex.profiles, 0.0, Sensors(), rng, mismatch=mm)
            t1 = time.perf_counter()
            fit = fit_friction(recs, base)
            rows.append(_row(fit, true, KEYS, time.perf_counter() - t1))
        out[name] = {"friction": mm.__dict__, "trials": n,
                     "flagged": int(sum(not r["adequate"] for r in rows)),
                     "flag_rate": float(np.mean([not r["adequate"] for r in rows])),
                     "coverage_count": {k: int(sum(r["cover"][k] for r in rows)) for k in KEYS},
                     "rel_error": {k: _stats([r["err"][k] for r in rows]) for k in KEYS},
                     "half_width_rel_median": {k: float(np.median([r["half"][k] for r in rows])) for k in KEYS}}
    return out


LEARN_BASELINES = [("energy-optimal", 0.0, 1.0, 1.0), ("energy-optimal", 1.0, 0.2, 0.6),
                   ("time-optimal", 0.2, -0.6, 0.8), ("energy-optimal", -0.6, 0.9, 1.5),
                   ("time-optimal", 0.9, 0.0, 0.5)]
LEARN_ROBUST = [(0.0, 1.0, 1.0), (0.2, -0.6, 0.8), (-0.6, 0.9, 1.5)]


def _learn(rng, base, n, noise=8e-5, q_sigma=1e-4):
    """Update from executions: a prior of pv ±30 %, pc, pt ±5 % around table 2, arms drawn from it."""
    prior = prior_from_box(base, {"pv": 0.3, "pc": 0.05, "pt": 0.05})
    sets = {"baseline": [(plan(PlanRequest(q0=(a,), qf=(b,), tf=tf, objective=o, params=base)).profile, a)
                         for o, a, b, tf in LEARN_BASELINES],
            "robust": [(plan(PlanRequest(q0=(a,), qf=(b,), tf=tf, objective="robust-derivative", starts=10,
                                         params=base)).profile, a) for a, b, tf in LEARN_ROBUST]}
    out = {"prior_box95": {"pv": 0.3, "pc": 0.05, "pt": 0.05}, "rest_noise_rad": noise, "q_sigma_rad": q_sigma,
           "encoder_counts": Sensors().counts_per_rev, "trials": n}
    for name, profs in sets.items():
        rows = []
        for _ in range(n):
            true = base.replace(**dict(zip(KEYS, rng.multivariate_normal(prior.mean, prior.cov))))
            exs = [Execution(p, q0, measure_rest(true, p, q0, rng, Sensors(), noise), q_sigma) for p, q0 in profs]
            t1 = time.perf_counter()
            res = update_from_executions(prior, exs)
            wall = time.perf_counter() - t1
            rows.append({"err_prior": {k: float(prior.mean[i] / getattr(true, k) - 1.0) for i, k in enumerate(KEYS)},
                         "err": {k: res.estimates[k] / getattr(true, k) - 1.0 for k in KEYS},
                         "cover": {k: res.interval95[k][0] <= getattr(true, k) <= res.interval95[k][1] for k in KEYS},
                         "std_ratio": {k: res.std[k] / float(prior.std[i]) for i, k in enumerate(KEYS)},
                         "bits": [e.information_bits for e in res.executions], "consistent": res.adequate,
                         "wall_s": wall})
        out[name] = {"executions": len(profs),
                     "rel_error_prior": {k: _stats([r["err_prior"][k] for r in rows]) for k in KEYS},
                     "rel_error_updated": {k: _stats([r["err"][k] for r in rows]) for k in KEYS},
                     "coverage_count": {k: int(sum(r["cover"][k] for r in rows)) for k in KEYS},
                     "std_ratio_median": {k: float(np.median([r["std_ratio"][k] for r in rows])) for k in KEYS},
                     "bits_per_execution_median": float(np.median([b for r in rows for b in r["bits"]])),
                     "bits_per_execution_max": float(np.max([b for r in rows for b in r["bits"]])),
                     "consistent_count": int(sum(r["consistent"] for r in rows)),
                     "update_wall_s": _stats([r["wall_s"] for r in rows])}
    return out


def _checks(offline, rows):
    n = len(rows)
    worst = {k: float(np.max(np.abs([r["err"][k] for r in rows]))) for k in KEYS}
    cover = {k: int(sum(r["cover"][k] for r in rows)) for k in KEYS}
    motion = float(max(r["motion_s"] for r in rows))
    return {"trials": n, "max_rel_error": worst, "coverage_count": cover,
            "coverage_all_three_count": int(sum(all(r["cover"].values()) for r in rows)),
            "motion_s": motion,
            "pc_pt_within_3pct": worst["pc"] <= 0.03 and worst["pt"] <= 0.03, "pv_within_10pct": worst["pv"] <= 0.10,
            "motion_at_most_60s": motion <= 60.0, "coverage_at_least_18_of_20": min(cover.values()) >= 0.9 * n}


STACK_ENVELOPE = Envelope(-1.0, 1.0, 3.0, i_max=3.0)
STACK_TIMING_MARGIN = 0.02       # s: the envelope holds with the brake switch or the final zero this late


def _stack_row(fit, true, wall, meta):
    row = _row(fit, true, KEYS, 0.0)
    row.update({"truth": {k: float(getattr(true, k)) for k in KEYS}, "estimates": dict(fit.estimates),
                "interval95": {k: list(fit.interval95[k]) for k in KEYS}, "message": fit.message,
                "rms_rad": fit.rms, "sigma_rad": fit.sigma, "stack_wall_s": wall,
                "stack_faults": meta.get("stack_faults", []), "timing": meta.get("timing"),
                "bus": meta.get("bus"),
                "sim_late_switches": meta.get("sim_late_switches"),
                "switch_delay_max_s": float(max((max(d) for d in meta["switch_delays"]), default=0.0))})
    return row


def _bridge_stamps_fit(outcomes, bus, q_res, base, true):
    """The same runs fitted with the bridge's joint states placed by their stamps (the
    path before the samples were read off the bus), for comparison."""
    from ff_executor.bringup.identify import StackFault, bus_timing
    from ff_planner.identify.records import RunRecord

    recs = []
    for mv, prof in outcomes:
        t, q, _, eff = mv.joints.arrays()
        try:
            tt, applied, keep = bus_timing(bus, t, prof, float(mv.profile_start))
        except StackFault:
            continue
        order = np.argsort(tt, kind="stable")
        tt, qq, ee = tt[order], q[keep, 0][order], eff[keep, 0][order]
        new = np.concatenate([[True], np.diff(tt) > 0.0])
        recs.append(RunRecord(tt[new], qq[new], ee[new], applied, q_res))
    if not recs:
        return None
    fit = fit_friction(recs, base)
    return {"adequate": fit.adequate, "rms_over_sigma": fit.rms / fit.sigma, "runs": len(recs),
            "err": {k: fit.estimates[k] / getattr(true, k) - 1.0 for k in KEYS},
            "cover": {k: fit.interval95[k][0] <= getattr(true, k) <= fit.interval95[k][1] for k in KEYS},
            "message": fit.message}


def _stack(rng, base, n, n_mismatch, seed):
    """Identification on ONE simulated stack (sync setpoints, bus timing), the arm's true
    friction set at runtime per trial; per trial estimates, errors and intervals."""
    from ff_executor.bringup.identify import (StackProbe, bus_monitor, identification_options, identify_runs,
                                              stack_q_resolution)
    from ff_executor.bringup.stack import Stack
    from ff_executor.ros.client import StackClient

    if seed is not None:
        rng = np.random.default_rng(seed)
    env = STACK_ENVELOPE
    ex = design_excitation(base, env, 0.0, timing_margin=STACK_TIMING_MARGIN)
    q_res = stack_q_resolution(base)
    out = {"excitation": {"levels_A": sorted({round(r.level, 4) for r in ex.runs}), "runs": len(ex.runs),
                          "motion_s": ex.duration, "envelope": {"q": [env.q_min, env.q_max], "v_max": env.v_max,
                                                                "i_max": env.i_max},
                          "timing_margin_s": STACK_TIMING_MARGIN},
           "q_resolution_rad": q_res, "seed": seed}
    t_all = time.perf_counter()
    with Stack(identification_options(), log=lambda s: None) as stack:
        out["stack_options"] = {"setpoint_timing": stack.options.setpoint_timing,
                                "executor": dict(stack.options.executor_overrides),
                                "rt_priority": stack.options.rt_priority}
        bus = bus_monitor(stack)
        client = StackClient(stack.env, "bench_identify")
        probe = StackProbe(client)
        try:
            def trial(true, friction=None):
                stack.set_true_params({k: float(getattr(true, k)) for k in KEYS})
                stack.set_sim_friction(friction or {"stribeck": 0.0, "coulomb_ripple": 0.0})
                client.reset_arm([0.0])
                t1 = time.perf_counter()
                outcomes: list = []
                try:
                    recs, meta = identify_runs(client, ex, q_res, env, bus=bus, probe=probe, log=lambda s: None,
                                               outcomes=outcomes)
                except RuntimeError:
                    # the trial counts as failed; a latched safe state must not fail the next ones
                    probe.fault_reset()
                    raise
                wall = time.perf_counter() - t1
                row = _stack_row(fit_friction(recs, base), true, wall, meta)
                row["bridge_stamps"] = _bridge_stamps_fit(outcomes, bus, q_res, base, true)
                return row


            rows, failed = [], []
            for i in range(n):
                true = _draw(rng, base, False)
                try:
                    rows.append(trial(true))
                except RuntimeError as exc:        # an envelope stop or a stack fault: counted
                    failed.append({"trial": i, "truth": {k: float(getattr(true, k)) for k in KEYS},
                                   "error": str(exc).splitlines()[0]})
            if n:
                out["eq9"] = _summarise(rows, KEYS) if rows else {"trials": 0}
                out["eq9"].update({"failed": failed, "runs": rows,
                                   "coverage_count": {k: int(sum(r["cover"][k] for r in rows)) for k in KEYS},
                                   "false_mismatch": int(sum(not r["adequate"] for r in rows)),
                                   "rms_over_sigma_max": max((r["rms_rad"] / r["sigma_rad"] for r in rows),
                                                             default=None)})
                bridge = [r["bridge_stamps"] for r in rows if r.get("bridge_stamps")]
                out["eq9"]["bridge_stamps"] = {
                    "trials": len(bridge), "false_mismatch": int(sum(not b["adequate"] for b in bridge)),
                    "rms_over_sigma": sorted(round(b["rms_over_sigma"], 2) for b in bridge)}
                out["checks"] = _checks(None, rows) if rows else {}
                if out["checks"]:       # a trial the stack did not complete counts against coverage
                    c = out["checks"]
                    c.update(failed_trials=len(failed), trials_attempted=n,
                             coverage_at_least_18_of_20=min(c["coverage_count"].values()) >= 0.9 * n,
                             false_mismatch=out["eq9"]["false_mismatch"],
                             false_mismatch_at_most_1_in_20=out["eq9"]["false_mismatch"] <= max(1, n // 20))
            if n_mismatch:
                out["mismatch"] = {}
                for name, mm in MISMATCHES.items():
                    fr = {"stribeck": mm.stribeck, "stribeck_speed": mm.stribeck_speed,
                          "coulomb_ripple": mm.coulomb_ripple, "coulomb_period": mm.coulomb_period}
                    mrows, mfailed = [], []
                    for i in range(n_mismatch):
                        true = _draw(rng, base, False)
                        try:
                            mrows.append(trial(true, fr))
                        except RuntimeError as exc:
                            mfailed.append({"trial": i, "error": str(exc).splitlines()[0]})
                    out["mismatch"][name] = {
                        "friction": fr, "trials": len(mrows), "failed": mfailed,
                        "flagged": int(sum(not r["adequate"] for r in mrows)),
                        "coverage_count": {k: int(sum(r["cover"][k] for r in mrows)) for k in KEYS},
                        "rel_error": {k: _stats([r["err"][k] for r in mrows]) for k in KEYS} if mrows else {},
                        "runs": mrows}
                stack.set_sim_friction({"stribeck": 0.0, "coulomb_ripple": 0.0})
            out["bus"] = {"syncs": bus.syncs, "tpdo_unpaired": bus.unpaired}
        finally:
            client.close()
            bus.close()
    out["wall_s"] = time.perf_counter() - t_all
    return out


#: the true friction of the --stack-plan arm: all three off table 2 (pv −15 %, pc +20 %, pt −15 %)
PLAN_TRUTH = {"pv": -0.0425, "pc": 0.228, "pt": 0.187}


def _stack_plan(base, n):
    """Identify once on a stack (planner on), plan robust-box over the identified box through the
    planner service and execute it n times from rest at 0 rad (every run counts): rest errors
    against the certificate (+ the switch timing measured on the bus)."""
    from ff_executor.bringup.identify import StackProbe, bus_monitor, identification_options
    from ff_executor.bringup.loop import box_of, execute_plan, identify_friction, params_of, plan_request
    from ff_executor.bringup.stack import Stack
    from ff_executor.ros.client import StackClient

    t0 = time.perf_counter()
    with Stack(identification_options(PLAN_TRUTH, planner=True), log=lambda s: None) as stack:
        bus = bus_monitor(stack)
        try:
            with StackClient(stack.env, "bench_identify_plan") as client:
                probe = StackProbe(client)
                idf = identify_friction(client, base, bus=bus, probe=probe)
                req = plan_request("robust-box", params_of(idf.fit), box_of(idf))
                runs = [execute_plan(client, f"run {k + 1}", req, bus=bus, probe=probe)[0].to_dict()
                        for k in range(n)]
        finally:
            bus.close()
    return {"truth": PLAN_TRUTH, "identification": idf.summary(PLAN_TRUTH), "runs": runs,
            "within_certificate": int(sum(r["within_certificate"] for r in runs)),
            "within_certificate_alone": int(sum(r["within_certificate_alone"] for r in runs)),
            "executed": int(sum(r["executed"] for r in runs)), "n": n,
            "rest_error_rad": _stats([r["error_truth"] for r in runs if r["executed"]]) if runs else None,
            "wall_s": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fit-inertia", action="store_true")
    ap.add_argument("--stack", type=int, default=0, help="trials on the simulated ROS stack too")
    ap.add_argument("--stack-mismatch", type=int, default=0,
                    help="trials per kind of friction that is not Eq. 9 on the stack's simulated arm")
    ap.add_argument("--stack-plan", type=int, default=0, metavar="N",
                    help="identify once on the stack, then run the box-robust plan over the identified box N times")
    ap.add_argument("--stack-seed", type=int, default=None,
                    help="seed of the stack trials' draw (default: continue the offline draw)")
    ap.add_argument("--mismatch", type=int, default=0, help="trials per kind of friction that is not Eq. 9")
    ap.add_argument("--learn", type=int, default=0, help="trials of the update from executions")
    ap.add_argument("--issue", action="store_true", help="--trials 20 --mismatch 20 --learn 20 and the checks")
    a = ap.parse_args()
    if a.issue:
        a.trials, a.mismatch, a.learn = 20, max(a.mismatch, 20), max(a.learn, 20)
    base = preset("table2")
    assert isinstance(base, Arm1DofParams)
    env = Envelope(-1.0, 1.0, 3.0)
    t0 = time.perf_counter()
    ex = design_excitation(base, env, 0.0)
    design_s = time.perf_counter() - t0
    keys = KEYS + (("J",) if a.fit_inertia else ())
    rng = np.random.default_rng(a.seed)
    rows = []
    for _ in range(a.trials):
        true = _draw(rng, base, a.fit_inertia)
        recs = measure_runs(true, ex.profiles, 0.0, Sensors(), rng)
        t1 = time.perf_counter()
        fit = fit_friction(recs, base, fit_inertia=a.fit_inertia)
        rows.append(_row(fit, true, keys, time.perf_counter() - t1))
    out = {"benchmark": "identify", "setup": {
        "truth": "pv, pc, pt uniform within ±30 % of table 2" + (", J ±10 %" if a.fit_inertia else ""),
        "excitation": {"levels_A": sorted({round(r.level, 4) for r in ex.runs}), "runs": len(ex.runs),
                       "motion_s": ex.duration, "envelope": {"q": [env.q_min, env.q_max], "v_max": env.v_max},
                       "design_s": design_s},
        "sensors": Sensors().__dict__, "seed": a.seed},
        "offline": _summarise(rows, keys)}
    out["offline"]["coverage_count"] = {k: int(sum(r["cover"][k] for r in rows)) for k in keys}
    if a.issue:
        out["checks"] = _checks(out["offline"], rows)
    if a.mismatch:
        t1 = time.perf_counter()
        out["mismatch"] = _mismatch(rng, base, ex, a.mismatch)
        out["mismatch"]["wall_s"] = time.perf_counter() - t1
    if a.learn:
        out["learn"] = _learn(rng, base, a.learn)
    if a.stack or a.stack_mismatch:
        out["stack"] = _stack(rng, base, a.stack, a.stack_mismatch, a.stack_seed)
    if a.stack_plan:
        out["stack_plan"] = _stack_plan(base, a.stack_plan)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()

"""``ff-demo``: the whole loop — identify the simulated arm's friction, plan over what was
identified, execute, and compare with plans made on the paper's table values.

    ff-demo                                  # true friction pv −15 %, pc +20 %, pt −15 % of table 2
    ff-demo --draw 7                         # true friction drawn within ±30 % of table 2, seed 7
    ff-demo --true-scale pc=0.8 --plot docs/demo/demo.png --json out.json
    ff-demo --domain-id 42 --record demo_bag   # a fixed domain (else ROS_DOMAIN_ID, else a free one); a bag
    ff-demo --print-config                     # the effective configuration, nothing started

1. Brings up the simulated stack (``ff_executor.bringup.stack.Stack`` with
   ``identify.identification_options``: CAN hub on 127.0.0.1 producing SYNC, sim driver, bridge
   latching setpoints at SYNC, planner rounding currents to the drive's 3 mA, executor;
   loopback-only ROS on a free domain, or ROS_DOMAIN_ID when set). The simulated arm's friction
   is not what the planner's model says, and the demo does not tell the planner.
2. Identifies pv, pc, pt from 8 constant-current runs (18.8 s of arm motion, inside
   q ∈ [−1, 1] rad, |q̇| ≤ 3 rad/s, ≤ 3 A) through the executor action, timed on the CAN bus
   (``ff_executor.bringup.loop.identify_friction``): estimates, 95 % intervals, the box.
3. Plans 0 → ``--qf`` rad in ``--tf`` s through the planner SERVICE: box-robust over the
   identified box on the identified friction; box-robust on the paper's table values (default
   ±20 % box); and the non-robust energy-optimal baseline on the table values.
4. Executes each once (every run counts: no repeats) from rest at 0 rad and prints where each
   came to rest beside its certificate (the worst rest error over the box it was planned for);
   saves a PNG (identification fit, positions, currents) and, with ``--json``, everything.

Exit 0 when all moves ran, the identified box-robust plan landed within its certificate and
within ``--tolerance`` (0.02 rad) of the goal, and the baseline missed by ``--min-ratio`` (3)
times more; 1 otherwise.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from ff_executor.bringup.stack import (BringupError, Stack, add_environment_arguments,
                                      environment_options, parse_key_values, print_config)
from ff_executor.ros.client import StackCallError, StackClient
from ff_msgs.srv import PlanTrajectory
from ff_msgs_py.convert import msg_to_profile
from ff_planner.model.params import Arm1DofParams, ParameterError, default_params
from ff_planner.model.simulate import rest_position

MOTIONS = (("robust", "robust-derivative"), ("baseline", "energy-optimal"))


def plan_request(objective: str, qf: float = 1.0, tf: float = 1.0, starts: int = 0,
                 seed: int = 1) -> PlanTrajectory.Request:
    """The demo's 1-DOF request: 0 → ``qf`` rad in ``tf`` s, pv, pc, pt uncertain."""
    return PlanTrajectory.Request(model="arm1dof", q0=[0.0], qf=[qf], move_time=tf,
                                  uncertain=["pv", "pc", "pt"], objective=objective,
                                  starts=starts, seed=seed)


def nominal_rest(profile_msg) -> list[float]:
    """The planner's nominal model's rest position (rad per joint) for a profile message."""
    return [float(x) for x in rest_position(default_params(profile_msg.model or "arm1dof"),
                                            msg_to_profile(profile_msg), list(profile_msg.q0))]


def run_motions(client: StackClient, qf: float = 1.0, tf: float = 1.0, motions=MOTIONS, log=print) -> dict:
    """Plan each motion via the service and execute it once on the simulated arm (every run
    counts: no repeats); returns a summary per motion, with the model's predicted rest position
    for the profile (``predicted_position``, from the executor's result) beside the measured one."""
    out = {}
    for label, objective in motions:
        t0 = time.monotonic()
        resp = client.plan(plan_request(objective, qf, tf))
        plan_s = time.monotonic() - t0
        if resp.profile.n_steps == 0:
            raise RuntimeError(f"planner gave no {objective} profile: {resp.message}")
        log(f"  planned {label} ({objective}): success={resp.success} robust={resp.robust} "
            f"{resp.profile.n_steps} steps, {plan_s * 1e3:.0f} ms"
            + ("" if resp.success else f" — {resp.message}"))
        client.reset_arm([0.0])
        mv = client.execute(resp.profile)
        final_truth = float(mv.rest_truth[0]) if mv.rest_truth is not None else math.nan
        r = mv.result
        predicted, source = list(r.predicted_position), "executor result"
        if not predicted:        # a profile without predicted_rest: the nominal model, here
            predicted = [float(x) for x in nominal_rest(resp.profile)]
            source = "nominal model (client)"
        log(f"  executed {label}: {mv.result.message}; switch spread {mv.switch_spread * 1e6:.0f} us"
            + (f"; model predicted {predicted[0]:+.6f} rad" if predicted else ""))
        out[label] = {
            "objective": objective, "plan_success": bool(resp.success), "robust": bool(resp.robust),
            "steps": int(resp.profile.n_steps), "plan_time_s": plan_s,
            "sensitivities": dict(zip(resp.sensitivity_names, map(float, resp.sensitivity_values))),
            "executed": mv.succeeded, "message": r.message,
            "final_position": list(r.final_position), "final_velocity": list(r.final_velocity),
            "error": float(r.position_error[0]) if len(r.position_error) else math.nan,
            "error_truth": final_truth - qf,
            "predicted_position": predicted, "predicted_source": source,
            "measured_minus_predicted": (final_truth - predicted[0]) if predicted else math.nan,
            "missed_cycles": int(r.missed_cycles), "sync_period_s": float(r.sync_period),
            "setpoints_sent": int(r.setpoints_sent), "start_delay_s": float(r.start_delay),
            "switch_error_s": {"p50": r.switch_error_p50, "p99": r.switch_error_p99,
                               "max": r.switch_error_max},
            "switch_spread_s": mv.switch_spread,
            "feedback_messages": mv.feedback, "feedback_gap_max_s": mv.feedback_period_max,
            "feedback_rate_hz": mv.feedback_rate,
            "_profile": resp.profile, "_outcome": mv,
        }
    return out


def plot(summary: dict, path: str, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    colours = {"robust": "tab:blue", "baseline": "tab:red"}
    for label, s in summary.items():
        mv, prof = s["_outcome"], s["_profile"]
        t, q, _, _ = mv.truth.arrays()
        tj, _, _, eff = mv.joints.arrays()
        t_start = mv.profile_start if mv.profile_start is not None else _start_of(mv, t, q)
        c = colours.get(label, None)
        name = f"{label} ({s['objective']}): error {s['error_truth'] * 1e3:+.2f} mrad"
        if t.size:
            ax1.plot(t - t_start, q[:, 0], color=c, label=name)
        st = np.asarray(prof.step_times)
        cur = np.asarray(prof.currents)
        ax2.step(np.append(st, prof.move_time), np.append(np.append(cur, 0.0), 0.0)[: st.size + 1],
                 where="post", color=c, label=f"{label}: commanded")
        if tj.size and np.isfinite(eff).any():   # 100 Hz samples, each held until the next one
            ax2.step(tj - t_start, eff[:, 0], where="post", color=c, alpha=0.4, lw=0.8,
                     label=f"{label}: measured")
    ax1.axhline(1.0, color="k", lw=0.6, ls="--")
    ax1.set_ylabel("position (rad), ground truth")
    ends = [s["_outcome"].truth.t[-1] - (s["_outcome"].profile_start or 0.0)
            for s in summary.values() if s["_outcome"].truth.t and s["_outcome"].profile_start]
    ax1.set_xlim(-0.1, max(ends) if ends else 1.5)
    ax1.legend(loc="lower right", fontsize=8)
    ax1.set_title(title, fontsize=10)
    ax2.set_ylabel("motor current (A)")
    ax2.set_xlabel("time since the profile started (s)")
    ax2.legend(loc="lower left", fontsize=7, ncol=2)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _start_of(mv, t, q) -> float:
    """The profile's start on the recording's clock: first sample where the arm moved."""
    if t.size == 0:
        return 0.0
    moved = np.nonzero(np.abs(q[:, 0] - q[0, 0]) > 1e-6)[0]
    return float(t[moved[0]]) if moved.size else float(t[0])


#: the default true friction: all three parameters off table 2 (pv −15 %, pc +20 %, pt −15 %)
DEFAULT_SCALE = {"pv": 0.85, "pc": 1.2, "pt": 0.85}
FRICTION = ("pv", "pc", "pt")


def draw_friction(seed: int, spread: float = 0.3) -> dict[str, float]:
    """True pv, pc, pt drawn uniformly within ±``spread`` of table 2 (seeded), SI."""
    base = default_params("arm1dof")
    f = 1.0 + np.random.default_rng(seed).uniform(-spread, spread, 3)
    return {k: float(getattr(base, k)) * float(x) for k, x in zip(FRICTION, f)}


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="ff-demo", description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--true-scale", action="append", default=[], metavar="KEY=FACTOR",
                    help="true friction of the simulated arm relative to table 2 (default pv=0.85, pc=1.2, "
                         "pt=0.85)")
    ap.add_argument("--true-param", action="append", default=[], metavar="KEY=VALUE",
                    help="absolute true parameter of the simulated arm (SI units)")
    ap.add_argument("--draw", type=int, default=None, metavar="SEED",
                    help="draw the true pv, pc, pt uniformly within ±30 %% of table 2 with this seed")
    ap.add_argument("--qf", type=float, default=1.0, help="goal, rad (start 0)")
    ap.add_argument("--tf", type=float, default=1.0, help="move time, s")
    ap.add_argument("--tolerance", type=float, default=0.02,
                    help="rad, the identified box-robust move must land within")
    ap.add_argument("--min-ratio", type=float, default=3.0,
                    help="the baseline must miss at least this many times more than the identified plan")
    ap.add_argument("--plot", default="ff-demo.png", help="PNG to write")
    ap.add_argument("--json", default=None, help="also write the summary as JSON here")
    add_environment_arguments(ap)
    ap.add_argument("--rt-priority", type=int, default=10, metavar="N",
                    help="SCHED_FIFO priority of the simulated driver and the bridge's scheduler "
                         "thread where permitted (else nice -10); 0 = normal scheduling")
    return ap


def loop_plot(identified, landings: dict, path: str, title: str) -> None:
    """PNG: the identification runs (measured vs fitted), positions and currents of the moves."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax0, ax1, ax2) = plt.subplots(3, 1, figsize=(9, 10), gridspec_kw={"height_ratios": [1.2, 1.4, 1]})
    fit = identified.fit
    off = 0.0
    for i, (t, qm, qf) in enumerate(zip(fit.times, fit.measured, fit.fitted)):
        tt = t - t[0] + off
        ax0.plot(tt, qm, color="k", lw=1.4, label="measured (bridge encoder, bus time)" if i == 0 else None)
        ax0.plot(tt, qf, color="tab:orange", lw=0.9, ls="--", label="fitted Eq. 9" if i == 0 else None)
        off = float(tt[-1]) + 0.2
    est = ", ".join(f"{k} = {fit.estimates[k]:.4g}" for k in FRICTION)
    ax0.set(ylabel="q (rad)", xlabel="identification runs back to back (s)",
            title=f"identified {est}; residual rms {fit.rms * 1e6:.1f} µrad", )
    ax0.legend(fontsize=7, loc="upper right")
    colours = {"identified box-robust": "tab:green", "table box-robust": "tab:blue",
               "table energy-optimal": "tab:red"}
    for label, (landing, resp, mv) in landings.items():
        t, q, _, _ = mv.truth.arrays()
        t0 = mv.profile_start if mv.profile_start is not None else _start_of(mv, t, q)
        c = colours.get(label)
        if t.size:
            ax1.plot(t - t0, q[:, 0], color=c, label=f"{label}: {landing.error_truth * 1e3:+.2f} mrad "
                     f"(certificate {landing.certificate_worst * 1e3:.1f})")
        prof = resp.profile
        st = np.asarray(prof.step_times)
        cur = np.asarray(prof.currents)
        ax2.step(np.append(st, prof.move_time), np.append(np.append(cur, 0.0), 0.0)[: st.size + 1],
                 where="post", color=c, label=label)
    ax1.axhline(1.0, color="k", lw=0.6, ls="--")
    ax1.set(ylabel="position (rad), ground truth", xlim=(-0.1, 1.6))
    ax1.legend(loc="lower right", fontsize=7)
    ax1.set_title(title, fontsize=9)
    ax2.set(ylabel="motor current (A), commanded", xlabel="time since the profile started (s)", xlim=(-0.1, 1.6))
    ax2.legend(loc="lower left", fontsize=7)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv: Optional[Sequence[str]] = None) -> int:
    from ff_executor.bringup.identify import StackProbe, bus_monitor, identification_options
    from ff_executor.bringup.loop import box_of, execute_plan, identify_friction, params_of
    from ff_executor.bringup.loop import plan_request as loop_request

    a = build_parser().parse_args(argv)
    try:
        if a.draw is not None and (a.true_scale or a.true_param):
            raise ValueError("--draw gives all three true parameters: no --true-scale / --true-param with it")
        scale = parse_key_values(a.true_scale, "--true-scale") if a.true_scale or a.true_param else \
            ({} if a.draw is not None else dict(DEFAULT_SCALE))
        absolute = draw_friction(a.draw) if a.draw is not None else parse_key_values(a.true_param, "--true-param")
        if not 0 <= a.rt_priority <= 99:
            raise ValueError(f"--rt-priority must be 0..99, got {a.rt_priority}")
        opts = identification_options(absolute, planner=True, rt_priority=a.rt_priority, true_scale=scale,
                                      **environment_options(a))
        true = opts.true_friction()
    except (ParameterError, ValueError) as exc:
        print(f"ff-demo: {exc}", file=sys.stderr)
        return 2
    if not (math.isfinite(a.qf) and math.isfinite(a.tf) and a.tf > 0.05):
        print("ff-demo: --qf must be finite and --tf > 0.05 s", file=sys.stderr)
        return 2
    if a.print_config:
        print_config(Stack(opts, log=lambda _m: None))
        return 0
    base = default_params("arm1dof")
    assert isinstance(base, Arm1DofParams)
    truth = {k: float(true.get(k, getattr(base, k))) for k in FRICTION}
    print(f"ff-demo: identify -> plan box-robust over the identified box -> execute, 0 -> {a.qf:g} rad in "
          f"{a.tf:g} s; the simulated arm's friction is not the paper's table 2 (kept from the planner "
          "until the end)", flush=True)
    t_start = time.monotonic()
    try:
        with Stack(opts) as stack:
            bus = bus_monitor(stack)
            try:
                with StackClient(stack.env, "ff_demo") as client:
                    print("identification (8 runs through the executor):", flush=True)
                    probe = StackProbe(client)
                    idf = identify_friction(client, base, bus=bus, probe=probe, log=print)
                    fit = idf.fit
                    print(f"  {fit.message}")
                    for k in FRICTION:
                        lo, hi = fit.interval95[k]
                        print(f"  {k} = {fit.estimates[k]:.6g}   95 % [{lo:.6g}, {hi:.6g}]   "
                              f"box ±{100 * idf.box[k]:.3g} %")
                    print("plans and moves (each once):", flush=True)
                    requests = {
                        "identified box-robust": loop_request("robust-box", params_of(fit), box_of(idf),
                                                              qf=a.qf, tf=a.tf),
                        "table box-robust": loop_request("robust-box", qf=a.qf, tf=a.tf),
                        "table energy-optimal": loop_request("energy-optimal", qf=a.qf, tf=a.tf),
                    }
                    landings = {label: execute_plan(client, label, req, bus=bus, probe=probe, log=print)
                                for label, req in requests.items()}
            finally:
                bus.close()
    except (BringupError, StackCallError, RuntimeError) as exc:
        print(f"ff-demo: failed: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 1
    wall = time.monotonic() - t_start
    print()
    print("the simulated arm's true friction: " + ", ".join(
        f"{k} = {truth[k]:.6g} ({100 * (truth[k] / float(getattr(base, k)) - 1):+.1f} % of table 2), "
        f"identified {fit.estimates[k]:.6g} ({100 * (fit.estimates[k] / truth[k] - 1):+.3f} %)" for k in FRICTION))
    print(f"\n{'plan':<22} {'planned on':<24} {'certificate (mrad)':>18} {'rest error (mrad)':>18} {'within':>7}")
    basis = {"identified box-robust": "identified, its box", "table box-robust": "table 2, ±20 % box",
             "table energy-optimal": "table 2 (not robust)"}
    for label, (L, _, _) in landings.items():
        print(f"{label:<22} {basis[label]:<24} {L.certificate_worst * 1e3:>18.3f} {L.error_truth * 1e3:>+18.3f} "
              f"{('yes' if L.within_certificate else 'no'):>7}")
    ident = landings["identified box-robust"][0]
    table = landings["table box-robust"][0]
    baseline = landings["table energy-optimal"][0]
    ratio = abs(baseline.error_truth) / max(abs(ident.error_truth), 1e-12)
    print(f"\nthe baseline misses by {ratio:.0f}x the identified plan's error; wall time {wall:.0f} s")
    off = ", ".join(f"{k} {100 * (truth[k] / float(getattr(base, k)) - 1):+.0f} %" for k in FRICTION)
    worst = max(abs(fit.estimates[k] / truth[k] - 1) for k in FRICTION) * 100
    title = f"true friction {off} of table 2; identified within {worst:.2g} %"
    loop_plot(idf, landings, a.plot, title)
    print(f"plot: {a.plot}")
    ok = (all(L.executed for L, _, _ in landings.values()) and ident.within_certificate
          and abs(ident.error_truth) <= a.tolerance and ratio >= a.min_ratio)
    if a.json:
        out = {"true_friction": truth, "table2": {k: float(getattr(base, k)) for k in FRICTION},
               "identification": idf.summary(truth),
               "motions": {label: L.to_dict() for label, (L, _, _) in landings.items()},
               "ratio_baseline_to_identified": ratio, "wall_s": wall, "ok": ok,
               "qf": a.qf, "tf": a.tf, "table_plan_within_its_certificate": table.within_certificate}
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps(out, indent=2, default=float))
    print("ff-demo: " + ("OK" if ok else f"FAILED (a move did not run, the identified plan missed its certificate "
                                         f"or {a.tolerance} rad, or the baseline was not {a.min_ratio:g}x worse)"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

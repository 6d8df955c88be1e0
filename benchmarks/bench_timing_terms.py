"""Each term between the model's rest position and the simulated stack's, measured alone; JSON.

For the robust 0 → 1 rad plan (robust-derivative, pv, pc, pt uncertain; planned here with the
library facade, or the profile the stack's planner returned, read from a ``bench_execution.py``
result with ``--from-execution FILE``: switches on the SYNC grid, currents on the 3 mA grid) and
the true friction of the benchmark (Coulomb +20 %), the exact simulator's rest position
(``ff_planner.model.simulate.rest_position``) is the reference; each term changes ONE thing and
reports the rest position's change (rad):

- ``physics_step``: the simulated arm (``ff_hwbridge.sim.arm.SimArm``, its default step and the
  model's ``advance``) fed the exact profile at the exact instants on a fake clock, run to rest;
- ``quantisation_epos4`` / ``quantisation_epos2``: every current rounded as the drive units do
  (``ff_hwbridge.protocol.units.DriveUnits``: EPOS4 0x6071 per mille of the nominal current, i.e.
  I_nominal / 1000 per step; EPOS2 0x2030 in mA);
- ``sync_grid``: every switch moved to the first SYNC at or after it (period ``--sync-period``),
  for ``--phases`` start phases of the profile against the SYNC grid: min / median / max;
- ``switch_sensitivity``: d(rest)/d(t_switch) per 100 µs of each switch (the certificate's
  ``switch_timing``), and the rest change of a switch-delay pattern (``--delays-us``, one per
  current change, relative to the first) both exactly and by the linear sensitivity.

    python benchmarks/bench_timing_terms.py [--sync-period 0.001] [--from-execution FILE] [--out FILE]
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from typing import Any

import numpy as np
from _common import arm1dof_params, report

from ff_hwbridge.protocol.units import DriveUnits
from ff_hwbridge.sim.arm import SimArm
from ff_planner.model.profile import CurrentProfile, PlanRequest
from ff_planner.model.simulate import rest_position
from ff_planner.optimize.certificate import switch_timing_1dof
from ff_planner.optimize.planner import plan

NS = 1_000_000_000
PC_SCALE = 1.2
NOMINAL_CURRENT = 3.0     # A, config/sim_arm1dof.yaml (the simulated EPOS4's motor)


def robust_profile() -> CurrentProfile:
    """The robust 0 -> 1 rad plan of the demo and the benchmarks (planner facade, nominal model)."""
    res = plan(PlanRequest(model="arm1dof", q0=[0.0], qf=[1.0], tf=1.0, uncertain=["pv", "pc", "pt"],
                           objective="robust-derivative", seed=1))
    if res.profile is None:
        raise RuntimeError(f"no plan: {res.message}")
    return res.profile


def executed_profile(path: str) -> tuple[CurrentProfile, str]:
    """The profile a ``bench_execution.py`` result ran (its ``plan``), and its task text."""
    with open(path, encoding="utf-8") as fh:
        data = json.load(fh)
    p = data["plan"]
    cur = np.asarray(p["currents_a"], float).reshape(-1, 1)
    return (CurrentProfile(np.asarray(p["step_times_s"], float), cur, float(p["tf_s"]), float(p["coast_s"])),
            str(data.get("task", p.get("objective", ""))) + f" (as the stack's planner returned it, {path})")


def arm_rest(params: Any, prof: CurrentProfile, step: float | None = None, settle: float = 3.0) -> float:
    """Rest position (rad) of the simulated arm fed ``prof`` at exact instants (fake clock)."""
    t = [0]
    arm = (SimArm(params, 0.0, clock=lambda: t[0]) if step is None
           else SimArm(params, 0.0, clock=lambda: t[0], step=step))
    for k in range(prof.n_steps):
        arm.set_current(0, float(prof.currents[k, 0]), int(round(prof.step_times[k] * NS)))
    arm.set_current(0, 0.0, int(round(prof.step_times[-1] * NS)))
    end = int(round((prof.tf + settle) * NS))
    st = arm.state(end)
    if abs(st.qd[0]) > 1e-9:
        raise RuntimeError(f"the simulated arm still moves at tf + {settle} s: {st.qd[0]} rad/s")
    return float(st.q[0])


def quantised(prof: CurrentProfile, units: DriveUnits) -> CurrentProfile:
    """The profile with every current as the drive receives it (setpoint integer back to A)."""
    cur = np.array([[units.setpoint_to_amps(units.amps_to_setpoint(float(c))) for c in row]
                    for row in prof.currents])
    return CurrentProfile(prof.step_times.copy(), cur, prof.tf, prof.coast)


def on_grid(prof: CurrentProfile, period: float, phase: float) -> CurrentProfile:
    """Each switch moved to the first SYNC at or after it; SYNCs at phase + k * period (s)."""
    st = prof.step_times.copy()
    t0 = math.ceil((st[0] - phase) / period - 1e-12) * period + phase     # the start's own SYNC
    st = np.array([math.ceil((s - phase) / period - 1e-12) * period + phase for s in st]) - t0
    return CurrentProfile(st, prof.currents, prof.tf, prof.tf - float(st[-1]))


def delayed(prof: CurrentProfile, delays: np.ndarray) -> CurrentProfile:
    """Each switch (steps and the final zero) later by ``delays`` s, relative to the first."""
    st = prof.step_times + (delays - delays[0])
    return CurrentProfile(st, prof.currents, prof.tf, prof.tf - float(st[-1]))


def main(argv: Any = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sync-period", type=float, default=0.001, help="s")
    ap.add_argument("--phases", type=int, default=50)
    ap.add_argument("--delays-us", default="", help="comma-separated switch delays (µs), one per change")
    ap.add_argument("--from-execution", default=None, metavar="FILE",
                    help="the profile of a bench_execution.py result (its 'plan') instead of planning here")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    t0 = time.monotonic()
    nominal = arm1dof_params()
    true = nominal.replace(pc=nominal.pc * PC_SCALE)
    if a.from_execution:
        prof, task = executed_profile(a.from_execution)
    else:
        prof, task = robust_profile(), "arm1dof 0 -> 1 rad in 1 s, robust-derivative"
    ref = float(rest_position(true, prof, [0.0])[0])
    out: dict[str, Any] = {"benchmark": "timing_terms", "task": task,
                           "true_params": {"pc": true.pc}, "steps": int(prof.n_steps),
                           "step_times_s": prof.step_times.tolist(), "currents_A": prof.currents[:, 0].tolist(),
                           "exact_rest_true_rad": ref,
                           "exact_rest_nominal_rad": float(rest_position(nominal, prof, [0.0])[0])}
    terms: dict[str, Any] = {}
    sim = arm_rest(true, prof)
    terms["physics_step"] = {"what": f"SimArm (step {SimArm(true, 0.0).step:g} s) fed the exact profile",
                             "rest_change_rad": sim - ref,
                             "step_1e-5_rest_change_rad": arm_rest(true, prof, step=1e-5) - ref}
    for fam in ("epos4", "epos2"):
        units = DriveUnits(family=fam, nominal_current=NOMINAL_CURRENT)
        q = quantised(prof, units)
        terms[f"quantisation_{fam}"] = {
            "step_A": (NOMINAL_CURRENT / 1000.0) if fam == "epos4" else 1e-3,
            "max_current_error_A": float(np.abs(q.currents - prof.currents).max()),
            "rest_change_rad": float(rest_position(true, q, [0.0])[0]) - ref}
    phases = np.linspace(0.0, a.sync_period, a.phases, endpoint=False)
    grid = np.array([float(rest_position(true, on_grid(prof, a.sync_period, ph), [0.0])[0]) - ref
                     for ph in phases])
    terms["sync_grid"] = {"sync_period_s": a.sync_period, "phases": int(a.phases),
                          "rest_change_rad": {"min": float(grid.min()), "median": float(np.median(grid)),
                                              "max": float(grid.max()),
                                              "max_abs": float(np.abs(grid).max())}}
    sens = switch_timing_1dof(nominal, prof, 0.0)
    sens_true = switch_timing_1dof(true, prof, 0.0)
    terms["switch_sensitivity"] = {"rad_per_100us_nominal": sens, "rad_per_100us_true": sens_true,
                                   "sum_abs_rad_per_100us": float(np.sum(np.abs(sens_true)))}
    if a.delays_us:
        d = np.array([float(x) for x in a.delays_us.split(",")]) * 1e-6
        if d.size != prof.n_steps + 1:
            raise SystemExit(f"--delays-us needs {prof.n_steps + 1} values, got {d.size}")
        exact = float(rest_position(true, delayed(prof, d), [0.0])[0]) - ref
        lin = float(np.dot(sens_true, (d[1:] - d[0]) / 1e-4))
        terms["switch_delays"] = {"delays_s": d.tolist(), "rest_change_exact_rad": exact,
                                  "rest_change_linear_rad": lin}
    out["terms"] = terms
    out["wall_s"] = time.monotonic() - t0
    report(out, a.out, default=float)
    return 0


if __name__ == "__main__":
    sys.exit(main())

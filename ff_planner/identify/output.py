"""What an identification hands on: the parameter file, the ``--json`` summary, a report (text + PNG).

The parameter file is the YAML of ``load_params`` / ``ff-plan --params`` (keys model, preset,
params); the uncertainty box (per friction parameter the fraction b with estimate·(1 ± b) ⊇ the
95 % interval, at least ``box_floor``) is written into it as a comment block, because
``load_params`` accepts those three keys only, and returned by :func:`summary` under "box".
Units: SI (Nm·s/rad, Nm, fraction, kg·m²).
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Mapping, Optional, Union

import numpy as np
import yaml

from ff_planner.identify.fit import FRICTION, FitResult
from ff_planner.identify.learn import COV_TAG, UpdateResult, prior_from_fit

#: what a parameter file can be written from: an identification or an update from executions
Estimate = Union[FitResult, UpdateResult]

UNITS = {"pv": "Nm·s/rad", "pc": "Nm", "pt": "fraction", "J": "kg·m²"}


def summary(fit: FitResult, box_floor: float = 0.02, extra: Optional[Mapping[str, Any]] = None) -> dict[str, Any]:
    """The ``--json`` dict: estimates, interval95 ([lo, hi]), std, box, adequacy tests (SI units)."""
    box = fit.relative_box(box_floor)
    box_args = " ".join(f"--box {k}={box[k]:.4g}" for k in FRICTION)
    out: dict[str, Any] = {
        "estimates": dict(fit.estimates),
        "interval95": {k: [lo, hi] for k, (lo, hi) in fit.interval95.items()},
        "std": dict(fit.std),
        "box": box,
        "adequate": fit.adequate,
        "message": fit.message,
        "tests": {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in fit.tests.items()},
        "rms_rad": fit.rms, "sigma_rad": fit.sigma, "n_runs": fit.n_runs, "n_samples": fit.n_samples,
        "motion_seconds": fit.motion_seconds, "method": fit.method, "units": {k: UNITS[k] for k in fit.keys},
        "ff_plan_box_args": box_args,
    }
    out.update(dict(extra or {}))
    return out


def covariance_line(fit: Estimate) -> str:
    """The ``# covariance`` comment of the parameter file: the covariance of (pv, pc, pt) (SI²)
    with the standard deviations of the 95 % intervals (half-width / 1.96) and the correlations of
    the estimate — the prior of a later update from executions (``learn.load_prior``)."""
    cov = fit.covariance if isinstance(fit, UpdateResult) else prior_from_fit(fit).cov
    return f"{COV_TAG} {json.dumps([[float(f'{v:.6g}') for v in row] for row in np.asarray(cov)])}"


def params_yaml(fit: Estimate, box_floor: float = 0.02, source: str = "") -> str:
    """The parameter file's text: model, preset, params (all of them, SI), and as comments the
    box, the 95 % intervals and the covariance of the friction parameters."""
    box = fit.relative_box(box_floor)
    box_args = " ".join(f"--box {k}={box[k]:.4g}" for k in FRICTION)
    head = ["# arm1dof parameters identified by ff-identify" + (f" from {source}" if source else ""),
            f"# fit: {fit.message}",
            "# uncertainty box (fraction of the estimate, covers the 95 % interval; use it as the",
            "# planner's friction uncertainty, e.g. the sampled-robust box):"]
    head += [f"#   {k}: {box[k]:.4g}    # 95 % interval [{fit.interval95[k][0]:.10g}, "
             f"{fit.interval95[k][1]:.10g}] {UNITS[k]}" for k in FRICTION]
    head.append(f"#   as ff-plan options: --uncertain pv pc pt {box_args}")
    head.append(covariance_line(fit))
    if not fit.adequate:
        head.append("# WARNING: the friction law does not fit the runs; treat these values with care")
    body = {"model": "arm1dof", "preset": "table2", "params": fit.params.to_dict()}
    return "\n".join(head) + "\n" + yaml.safe_dump(body, sort_keys=False)


def plan_config_yaml(fit: Estimate, box_floor: float = 0.02) -> str:
    """An ``ff-plan --config`` file: the identified parameters plus ``plan: {uncertain, box}``
    (the box fractions per friction parameter, for the planner's robust-box objective)."""
    box = fit.relative_box(box_floor)
    body = {"model": "arm1dof", "preset": "table2", "params": fit.params.to_dict(),
            "plan": {"uncertain": list(FRICTION), "box": {k: float(box[k]) for k in FRICTION}}}
    head = f"# ff-plan --config file from ff-identify; fit: {fit.message}\n"
    return head + yaml.safe_dump(body, sort_keys=False)


def write_params(path: str | Path, fit: Estimate, box_floor: float = 0.02, source: str = "") -> Path:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(params_yaml(fit, box_floor, source))
    return p


def report_text(fit: FitResult, truth: Optional[Mapping[str, float]] = None, box_floor: float = 0.02) -> str:
    """A plain-text report: method, estimates with intervals (and errors against ``truth``), tests."""
    box = fit.relative_box(box_floor)
    lines = ["ff-identify: friction of the 1-DOF arm (Eq. 9)", f"method: {fit.method}",
             f"runs: {fit.n_runs}, samples: {fit.n_samples}, arm motion: {fit.motion_seconds:.2f} s",
             f"residual rms: {fit.rms:.3g} rad (measurement alone: {fit.sigma:.3g} rad)", "",
             f"{'param':<6}{'estimate':>14}{'95 % interval':>32}{'box':>9}" + ("   true, error" if truth else "")]
    for k in fit.keys:
        lo, hi = fit.interval95[k]
        row = f"{k:<6}{fit.estimates[k]:>14.6g}   [{lo:>12.6g}, {hi:>12.6g}]"
        row += f"{box[k]:>9.3g}" if k in box else " " * 9
        if truth and k in truth:
            tv = float(truth[k])
            err = (fit.estimates[k] / tv - 1.0) * 100.0 if tv else math.nan
            row += f"   {tv:.6g}, {err:+.3f} %{'' if lo <= tv <= hi else '  (outside)'}"
        lines.append(row + f"  {UNITS[k]}")
    t = fit.tests
    lines += ["", f"whiteness (Ljung-Box): Q = {t['ljung_box_q']:.1f} on {t['ljung_box_dof']:.0f} dof, "
              f"p = {t['p_white']:.3g}"]
    if math.isfinite(t["chi2"]):
        lines.append(f"size (chi2 vs encoder quantum): {t['chi2']:.0f} on {t['chi2_dof']:.0f} dof, "
                     f"p = {t['p_chi2']:.3g}")
    lines += [f"verdict: {fit.message}"]
    return "\n".join(lines) + "\n"


def update_report_text(res: UpdateResult, box_floor: float = 0.02) -> str:
    """A plain-text report of an update from executions: prior and updated estimates with their
    intervals, and what each execution contributed."""
    box = res.relative_box(box_floor)
    lines = ["ff-identify --update: friction of the 1-DOF arm (Eq. 9) learned from executions",
             f"method: {res.method}", f"prior covariance from: {res.prior.source}", "",
             f"{'param':<6}{'prior':>12}{'± (95 %)':>12}{'updated':>14}{'95 % interval':>32}{'box':>9}"]
    for i, k in enumerate(FRICTION):
        lo, hi = res.interval95[k]
        lines.append(f"{k:<6}{res.prior.mean[i]:>12.6g}{1.96 * res.prior.std[i]:>12.3g}{res.estimates[k]:>14.6g}"
                     f"   [{lo:>12.6g}, {hi:>12.6g}]{box[k]:>9.3g}  {UNITS[k]}")
    lines += ["", f"{'execution':<32}{'bits':>7}{'error before':>15}{'after (mrad)':>14}"
              f"{'dq/dpv':>10}{'dq/dpc':>10}{'dq/dpt':>10}"]
    for e in res.executions:
        s = e.sensitivity
        lines.append(f"{e.name[:31]:<32}{e.information_bits:>7.2f}{1e3 * (e.measured - e.predicted_prior):>15.3f}"
                     f"{1e3 * (e.measured - e.predicted_posterior):>14.3f}"
                     f"{s['pv']:>10.3g}{s['pc']:>10.3g}{s['pt']:>10.3g}")
    lines += ["", f"information, all executions: {res.information_bits:.2f} bits",
              f"consistency: chi2 = {res.chi2:.3g} on {len(res.executions)} dof, p = {res.p_consistent:.3g}",
              f"verdict: {res.message}"]
    return "\n".join(lines) + "\n"


def plot_report(fit: FitResult, path: str | Path) -> Path:
    """PNG: measured vs fitted positions per run, residuals, parameter intervals (relative)."""
    from matplotlib.figure import Figure     # heavy: only when a report is asked for

    fig = Figure(figsize=(11, 8))
    ax = fig.subplots(3, 1, gridspec_kw={"height_ratios": [3, 2, 1.4]})
    offset = 0.0
    for i, (t, qm, qf, e) in enumerate(zip(fit.times, fit.measured, fit.fitted, fit.residuals)):
        tt = t - t[0] + offset
        ax[0].plot(tt, qm, color="k", lw=1.6, label="measured" if i == 0 else None)
        ax[0].plot(tt, qf, color="tab:orange", lw=0.9, ls="--", label="fitted model" if i == 0 else None)
        ax[1].plot(tt, e * 1e3, color="tab:blue", lw=0.6)
        offset = float(tt[-1]) + 0.2
    ax[0].set(ylabel="q (rad)", title=f"runs back to back — {fit.message[:90]}")
    ax[0].legend(fontsize=8, loc="upper right")
    ax[1].set(ylabel="residual (mrad)", xlabel="time, runs back to back (s)")
    ks = list(fit.keys)
    est = np.array([fit.estimates[k] for k in ks])
    lo = np.array([fit.interval95[k][0] for k in ks])
    hi = np.array([fit.interval95[k][1] for k in ks])
    rel = np.where(est != 0.0, 100.0 * (np.vstack([est - lo, hi - est])) / np.abs(est), 0.0)
    ax[2].errorbar(np.arange(len(ks)), np.zeros(len(ks)), yerr=rel, fmt="o", capsize=4)
    ax[2].set_xticks(np.arange(len(ks)), [f"{k} = {v:.4g}" for k, v in zip(ks, est)])
    ax[2].set(ylabel="95 % interval (%)")
    fig.tight_layout()
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, dpi=100)
    return p


def write_report(fit: FitResult, folder: str | Path, truth: Optional[Mapping[str, float]] = None,
                 box_floor: float = 0.02) -> list[Path]:
    """report.txt and fit.png in ``folder``; returns their paths."""
    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    txt = d / "report.txt"
    txt.write_text(report_text(fit, truth, box_floor))
    return [txt, plot_report(fit, d / "fit.png")]

"""Figures in the style of the paper's Fig. 5/7/11 (matplotlib, Agg; no display needed).

``plot_motion``: (a) current vs time, (b) position vs time at nominal and ±40 % friction,
(c) final position vs friction-parameter change, (d) final velocity vs change (1-DOF) or the
second joint's final position (SCARA). ``plot_curves``: generic x/y curves (e.g. Fig. 6).
Units on the axes: s, A, rad, rad/s; parameter changes in % of nominal.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping, Optional, Sequence, Union

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ff_planner.model.params import Params, friction_scaled
from ff_planner.model.profile import CurrentProfile
from ff_planner.model.simulate import simulate

_COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")


def save_figure(fig: Figure, path: Union[str, Path]) -> Path:
    p = Path(path)
    FigureCanvasAgg(fig)
    fig.savefig(p, dpi=110)
    return p


def step_xy(profile: CurrentProfile, j: int) -> tuple[np.ndarray, np.ndarray]:
    """Staircase of joint j's current (A) over [0, tf] (s), zero during the coast."""
    t = np.concatenate([profile.step_times, [profile.tf]])
    i = np.concatenate([profile.currents[:, j], [0.0, 0.0]])
    return np.repeat(t, 2)[1:], np.repeat(i, 2)[:-1]


def _scaled_runs(params: Params, profile: CurrentProfile, q0: Sequence[float],
                 names: Sequence[str], factors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """q(tf), q̇(tf) (rad, rad/s) for each name × factor (relative parameter scale)."""
    qf = np.full((len(names), len(factors), profile.n_joints), np.nan)
    qdf = np.full_like(qf, np.nan)
    for a, name in enumerate(names):
        for b, f in enumerate(factors):
            try:
                r = simulate(friction_scaled(params, {name: f}), profile, q0)
            except ValueError:
                continue   # e.g. a scale that makes a parameter invalid
            qf[a, b], qdf[a, b] = r.q_f, r.qd_f
    return qf, qdf


def plot_motion(params: Params, profile: CurrentProfile, q0: Sequence[float],
                qf: Sequence[float], uncertain: Sequence[str], path: Union[str, Path], *,
                spread: float = 0.4, sweep: float = 1.0, n_sweep: int = 81,
                title: Optional[str] = None) -> Path:
    """Write a Fig. 5/7-style PNG of a motion to ``path``; returns the path.

    ``spread``: the ± relative friction change of the dashed position curves (0.4 = ±40 %), each
    uncertain parameter alone. ``sweep``: the range (± relative) of the final-state panels.
    """
    goal = np.asarray(qf, dtype=float)
    names = list(uncertain) or list(params.friction_keys)
    nj = profile.n_joints
    fig = Figure(figsize=(11, 7.5))
    ax = fig.subplots(2, 2)
    # (a) current
    for j in range(nj):
        x, y = step_xy(profile, j)
        ax[0, 0].plot(x, y, color=_COLORS[j], label=f"joint {j + 1}")
    ax[0, 0].set(xlabel="t (s)", ylabel="current (A)", title="(a) feedforward current")
    if nj > 1:
        ax[0, 0].legend(fontsize=8)
    # (b) position at nominal and ±spread
    nom = simulate(params, profile, q0, trajectory=True)
    assert nom.t is not None and nom.q is not None      # sampled with trajectory=True
    for j in range(nj):
        ax[0, 1].plot(nom.t, nom.q[:, j], color=_COLORS[j], lw=2,
                      label="nominal" if j == 0 else None)
        ax[0, 1].axhline(goal[j], color="gray", lw=0.6, ls=":")
    for k, name in enumerate(names):
        for f, ls in ((1.0 - spread, "--"), (1.0 + spread, "-.")):
            try:
                r = simulate(friction_scaled(params, {name: f}), profile, q0, trajectory=True)
            except ValueError:
                continue
            assert r.t is not None and r.q is not None
            for j in range(nj):
                ax[0, 1].plot(r.t, r.q[:, j], color=_COLORS[(k + 2) % 6], ls=ls, lw=0.9,
                              label=f"{name} {f - 1:+.0%}" if j == 0 else None)
    ax[0, 1].set(xlabel="t (s)", ylabel="position (rad)",
                 title=f"(b) position, nominal and ±{spread:.0%} friction")
    ax[0, 1].legend(fontsize=7, ncol=2)
    # (c), (d) final state vs parameter change
    factors = 1.0 + np.linspace(-sweep, sweep, n_sweep)
    qfs, qdfs = _scaled_runs(params, profile, q0, names, factors)
    pct = (factors - 1.0) * 100.0
    for k, name in enumerate(names):
        ax[1, 0].plot(pct, qfs[k, :, 0], color=_COLORS[k % 6], label=name)
        if nj == 1:
            ax[1, 1].plot(pct, qdfs[k, :, 0], color=_COLORS[k % 6], label=name)
        else:
            ax[1, 1].plot(pct, qfs[k, :, 1], color=_COLORS[k % 6], label=name)
    ax[1, 0].axhline(goal[0], color="gray", lw=0.6, ls=":")
    ax[1, 0].set(xlabel="parameter change (%)", ylabel="q(tf) (rad)" if nj == 1 else "q1(tf) (rad)",
                 title="(c) final position vs friction change")
    if nj == 1:
        ax[1, 1].set(xlabel="parameter change (%)", ylabel="q̇(tf) (rad/s)",
                     title="(d) final velocity vs friction change")
    else:
        ax[1, 1].axhline(goal[1], color="gray", lw=0.6, ls=":")
        ax[1, 1].set(xlabel="parameter change (%)", ylabel="q2(tf) (rad)",
                     title="(d) joint 2 final position vs friction change")
    ax[1, 0].legend(fontsize=8)
    ax[1, 1].legend(fontsize=8)
    for a in ax.ravel():
        a.grid(True, lw=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_curves(x: Sequence[float], curves: Mapping[str, Sequence[float]],
                path: Union[str, Path], *, xlabel: str, ylabel: str, title: str = "",
                logy: bool = False, vlines: Optional[Mapping[str, float]] = None) -> Path:
    """Generic line plot of named curves over x (used for the Fig. 6 sweep)."""
    fig = Figure(figsize=(7.5, 4.5))
    a = fig.subplots()
    for k, (name, y) in enumerate(curves.items()):
        yv = np.asarray(y, dtype=float)
        a.plot(x, np.abs(yv) if logy else yv, marker=".", color=_COLORS[k % 6], label=name)
    for k, (name, xv) in enumerate((vlines or {}).items()):
        a.axvline(xv, color=_COLORS[k % 6], ls=":", lw=1, label=name)
    if logy:
        a.set_yscale("log")
    a.set(xlabel=xlabel, ylabel=ylabel, title=title)
    a.grid(True, lw=0.3)
    a.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)

"""The friction samples of the robust-sampled objective and of the finite-change verification.

One box for every planner (paper section 6.2): each uncertain parameter p_i at p_i·(1 ± level)
alone, for each level, and — with more than one uncertain parameter — the 2^k corners of the
±corner box, all of them together at p_i·(1 ± corner). Scale factors are dimensionless; a
sampled parameter value is its nominal value times its scale.
"""
from __future__ import annotations

import itertools
from typing import Mapping, Optional, Sequence

import numpy as np

SAMPLE_LEVELS = (0.1, 0.2)      # robust-sampled: one parameter at a time at ±10 % and ±20 %
SAMPLE_CORNER = 0.2             # and the corners of the ±20 % box
FINITE_FRACTIONS = (0.1, 0.4)   # verification: finite changes of ±10 % and ±40 %
SIGNS = (-1.0, 1.0)             # default order of the two signs in the tables


def signed_changes(fractions: Sequence[float] = FINITE_FRACTIONS) -> tuple[float, ...]:
    """Relative changes ±fractions in increasing order, e.g. (0.1, 0.4) -> (-0.4, -0.1, 0.1, 0.4)."""
    return tuple(sorted(s * f for f in fractions for s in SIGNS))


#: the finite relative changes of the verification sweeps (one at a time and all together)
FINITE_CHANGES = signed_changes(FINITE_FRACTIONS)


def one_at_a_time(uncertain: Sequence[str], levels: Sequence[float],
                  signs: Sequence[float] = SIGNS) -> list[tuple[str, float]]:
    """(parameter, relative change) for each uncertain parameter, each level, each sign."""
    return [(u, s * lv) for u in uncertain for lv in levels for s in signs]


def sample_scales(uncertain: Sequence[str], keys: Sequence[str],
                  levels: Sequence[float] = SAMPLE_LEVELS, corner: Optional[float] = SAMPLE_CORNER,
                  signs: Sequence[float] = SIGNS) -> np.ndarray:
    """Scale factors (S, len(keys)) over the parameters ``keys``: one row per ``one_at_a_time``
    change, then (with ``corner`` and more than one uncertain parameter) one row per corner of
    the ±corner box, signs in ``itertools.product(signs)`` order. A single row of ones when
    nothing is sampled."""
    col = {k: j for j, k in enumerate(keys)}
    rows = []
    for u, ch in one_at_a_time(uncertain, levels, signs):
        r = np.ones(len(keys))
        r[col[u]] = 1.0 + ch
        rows.append(r)
    if corner is not None and len(uncertain) > 1:
        for corner_signs in itertools.product(signs, repeat=len(uncertain)):
            r = np.ones(len(keys))
            for u, s in zip(uncertain, corner_signs):
                r[col[u]] = 1.0 + s * corner
            rows.append(r)
    return np.array(rows) if rows else np.ones((1, len(keys)))


# --- the uncertainty box of the robust-box objective and of the robustness certificate ------
BOX_FRACTION = 0.2     # default ± fraction of every uncertain parameter
BOX_CHECK_SEED = 20_240_611   # fixed seed of the planner's own check samples


def box_fractions(uncertain: Sequence[str], box: Optional[Mapping[str, float]] = None
                  ) -> dict[str, float]:
    """± fraction per uncertain parameter: ``box`` where given, else BOX_FRACTION."""
    given = dict(box or {})
    return {u: float(given.get(u, BOX_FRACTION)) for u in uncertain}


def _scaled(rows: np.ndarray, fractions: Mapping[str, float], keys: Sequence[str]) -> np.ndarray:
    """Scale factors (S, len(keys)) from unit-box rows (S, k) in [−1, 1] over ``fractions``."""
    out = np.ones((rows.shape[0], len(keys)))
    for j, (u, f) in enumerate(fractions.items()):
        out[:, list(keys).index(u)] = 1.0 + f * rows[:, j]
    return out


def box_corners(fractions: Mapping[str, float], keys: Sequence[str]) -> np.ndarray:
    """The 2^k corners of the box, then its centre: scale factors (2^k + 1, len(keys))."""
    k = len(fractions)
    rows = np.array(list(itertools.product(SIGNS, repeat=k)) + [(0.0,) * k], dtype=float)
    return _scaled(rows.reshape(2 ** k + 1, k), fractions, keys)


def box_faces(fractions: Mapping[str, float], keys: Sequence[str]) -> np.ndarray:
    """The 2k face centres of the box (each parameter alone at ±its fraction)."""
    k = len(fractions)
    rows = np.vstack([s * np.eye(k)[i] for i in range(k) for s in SIGNS]) if k else np.zeros((0, 0))
    return _scaled(rows.reshape(2 * k, k), fractions, keys)


def box_grid(fractions: Mapping[str, float], keys: Sequence[str], levels: int = 3) -> np.ndarray:
    """A full grid of ``levels`` values per parameter over the box (levels^k rows)."""
    axis = np.linspace(-1.0, 1.0, levels)
    rows = np.array(list(itertools.product(axis, repeat=len(fractions))), dtype=float)
    return _scaled(rows.reshape(levels ** len(fractions), len(fractions)), fractions, keys)


def box_uniform(fractions: Mapping[str, float], keys: Sequence[str], count: int,
                seed: int = BOX_CHECK_SEED) -> np.ndarray:
    """``count`` seeded points uniform in the box."""
    rng = np.random.default_rng(seed)
    rows = rng.uniform(-1.0, 1.0, (int(count), len(fractions)))
    return _scaled(rows, fractions, keys)


def box_samples(fractions: Mapping[str, float], keys: Sequence[str]) -> np.ndarray:
    """The robust-box objective's minimax samples: the 2^k corners, the centre and the 2k face
    centres."""
    return np.vstack([box_corners(fractions, keys), box_faces(fractions, keys)])


def box_minimax_samples(fractions: Mapping[str, float], keys: Sequence[str]) -> np.ndarray:
    """The robust-box minimax's starting samples: the 2^k corners only. The centre's rest error
    is zero on the robust set (q(tf) = qf, the arm at rest), and the face centres, the edges
    and the interior come in through the exchange from ``box_check_samples`` where they bind."""
    return box_corners(fractions, keys)[:-1]


def box_check_samples(fractions: Mapping[str, float], keys: Sequence[str],
                      count: int = 64) -> np.ndarray:
    """The planner's check set (exchange step): a 3^k grid and ``count`` seeded uniform points."""
    return np.vstack([box_grid(fractions, keys, 3), box_uniform(fractions, keys, count)])

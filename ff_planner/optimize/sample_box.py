"""The friction samples of the robust-sampled objective and of the finite-change verification.

One box for every planner (paper section 6.2): each uncertain parameter p_i at p_i·(1 ± level)
alone, for each level, and — with more than one uncertain parameter — the 2^k corners of the
±corner box, all of them together at p_i·(1 ± corner). Scale factors are dimensionless; a
sampled parameter value is its nominal value times its scale.
"""
from __future__ import annotations

import itertools
from typing import Optional, Sequence

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

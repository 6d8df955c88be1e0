"""Settle detection: when the arm has come to rest after a move."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from numpy.typing import ArrayLike

from ff_executor.engine.config import NS


@dataclass
class SettleDetector:
    """The arm has settled when every |velocity| <= ``velocity`` (rad/s) for ``hold`` s."""

    velocity: float = 1e-3
    hold: float = 0.05
    _since: Optional[int] = field(default=None, repr=False)

    def update(self, t_ns: int, velocities: ArrayLike) -> bool:
        """Feed one sample (ns, rad/s); True once at rest for ``hold`` s."""
        if np.all(np.abs(np.asarray(velocities, dtype=float)) <= self.velocity):
            if self._since is None:
                self._since = t_ns
            return t_ns - self._since >= int(round(self.hold * NS))
        self._since = None
        return False

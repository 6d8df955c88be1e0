"""Results shared by the simulators of every model."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np


@dataclass
class SimResult:
    """Final state at tf and, on request, the sampled trajectory.

    q_f, qd_f: (n_joints,) rad, rad/s at tf. t: (M,) s; q, qd: (M, n_joints); current: (M, n_joints)
    A — None unless a trajectory was requested. events: (t, kind) pairs, e.g. (0.12, "stick").
    """

    q_f: np.ndarray
    qd_f: np.ndarray
    t: Optional[np.ndarray] = None
    q: Optional[np.ndarray] = None
    qd: Optional[np.ndarray] = None
    current: Optional[np.ndarray] = None
    events: list = field(default_factory=list)

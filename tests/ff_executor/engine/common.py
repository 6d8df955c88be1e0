"""Shared inputs of the engine tests: a checked 1-DOF motion and a fake clock (ns)."""
from __future__ import annotations

from typing import Optional, Sequence

from ff_executor.engine import NS, EngineConfig, Motion, check_profile
from ff_planner.model.profile import CurrentProfile

CUR = [-3.70, 2.27, 0.58, 6.94, -4.76]   # A, five equal steps over 1 s


def motion(currents: Sequence[float] = CUR, names: Sequence[str] = ("joint1",),
           cfg: Optional[EngineConfig] = None, pid: str = "p1", q0: Sequence[float] = (0.0,),
           qf: Sequence[float] = (1.0,)) -> Motion:
    """``currents`` as uniform steps over tf = 1 s, checked against ``cfg`` (default EngineConfig())."""
    cfg = cfg or EngineConfig()
    prof = CurrentProfile.uniform(currents, 1.0)
    return check_profile(prof, names, q0, qf, cfg, pid)


class FakeClock:
    """A clock (ns) that advances only when slept on (at least 0.1 ms per sleep)."""

    def __init__(self, t0: int = 10 * NS) -> None:
        self.t = t0

    def __call__(self) -> int:
        return self.t

    def sleep(self, s: float) -> None:
        self.t += max(int(s * NS), 100_000)

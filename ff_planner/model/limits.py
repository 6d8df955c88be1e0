"""Workspace and speed limits of a move, and the excursion a plan makes against them.

A cell's limits hold along the WHOLE motion (powered part and coast, until the arm rests) at
every point of the friction box, not only at nominal. Units: rad, rad/s. Empty = no limit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional, Sequence

from ff_planner.core.errors import PlanningError


def _floats(values: Optional[Sequence[float]]) -> tuple[float, ...]:
    return tuple(float(v) for v in values) if values is not None else ()


@dataclass(frozen=True)
class MotionLimits:
    """Per-joint position range [position_min, position_max] (rad) and speed limit |qd| <=
    velocity_max (rad/s). Each sequence is empty (no such limit) or has one value per joint.
    Messages number joints from 1."""

    position_min: tuple[float, ...] = ()
    position_max: tuple[float, ...] = ()
    velocity_max: tuple[float, ...] = ()

    @classmethod
    def of(cls, position_min: Optional[Sequence[float]] = None,
           position_max: Optional[Sequence[float]] = None,
           velocity_max: Optional[Sequence[float]] = None) -> "MotionLimits":
        return cls(_floats(position_min), _floats(position_max), _floats(velocity_max))

    @property
    def empty(self) -> bool:
        return not (self.position_min or self.position_max or self.velocity_max)

    def validate(self, n_joints: int, q0: Sequence[float], qf: Sequence[float]) -> None:
        """Raise PlanningError with what to change; changes nothing."""
        for name, v in (("position_min", self.position_min), ("position_max", self.position_max),
                        ("velocity_max", self.velocity_max)):
            if v and len(v) != n_joints:
                raise PlanningError(f"{name} needs {n_joints} value(s) (one per joint) or none, "
                                    f"got {len(v)}")
            if any(math.isnan(x) for x in v):
                raise PlanningError(f"{name} must be numbers, got {list(v)}")
        if any(not (x > 0.0) for x in self.velocity_max):
            raise PlanningError(f"velocity_max must be > 0 rad/s, got {list(self.velocity_max)}")
        if self.position_min and self.position_max:
            for j, (lo, hi) in enumerate(zip(self.position_min, self.position_max)):
                if not lo < hi:
                    raise PlanningError(f"joint {j + 1}: position_min {lo:g} rad must be below "
                                        f"position_max {hi:g} rad")
        for name, q in (("start q0", q0), ("goal qf", qf)):
            for j, x in enumerate(q):
                if self.position_min and float(x) < self.position_min[j]:
                    raise PlanningError(f"joint {j + 1}: {name} = {float(x):g} rad is below "
                                        f"position_min {self.position_min[j]:g} rad; widen the "
                                        f"range or move the {name.split()[0]}")
                if self.position_max and float(x) > self.position_max[j]:
                    raise PlanningError(f"joint {j + 1}: {name} = {float(x):g} rad is above "
                                        f"position_max {self.position_max[j]:g} rad; widen the "
                                        f"range or move the {name.split()[0]}")

    def to_dict(self) -> dict:
        return {"position_min": list(self.position_min), "position_max": list(self.position_max),
                "velocity_max": list(self.velocity_max), "units": {"position": "rad",
                                                                   "velocity": "rad/s"}}


@dataclass
class Excursion:
    """Where a plan takes the arm, per joint, from t = 0 until rest (zero current after tf).

    nominal_*: at the nominal friction; worst_*: over the certificate's box points (the lowest
    position, the highest position and the largest |speed| found at any of them). rad, rad/s.
    """

    nominal_min: list[float] = field(default_factory=list)
    nominal_max: list[float] = field(default_factory=list)
    nominal_speed: list[float] = field(default_factory=list)
    worst_min: list[float] = field(default_factory=list)
    worst_max: list[float] = field(default_factory=list)
    worst_speed: list[float] = field(default_factory=list)

    def violations(self, limits: Optional[MotionLimits], slack: float = 0.0) -> list[str]:
        """The limits the worst excursion breaks (text per violation, empty = none)."""
        out: list[str] = []
        if limits is None:
            return out
        for j in range(len(self.worst_min)):
            if limits.position_min and self.worst_min[j] < limits.position_min[j] - slack:
                out.append(f"joint {j + 1} reaches {self.worst_min[j]:.4g} rad < position_min "
                           f"{limits.position_min[j]:.4g}")
            if limits.position_max and self.worst_max[j] > limits.position_max[j] + slack:
                out.append(f"joint {j + 1} reaches {self.worst_max[j]:.4g} rad > position_max "
                           f"{limits.position_max[j]:.4g}")
            if limits.velocity_max and self.worst_speed[j] > limits.velocity_max[j] + slack:
                out.append(f"joint {j + 1} reaches {self.worst_speed[j]:.4g} rad/s > velocity_max "
                           f"{limits.velocity_max[j]:.4g}")
        return out

    def to_dict(self) -> dict:
        f = lambda v: [float(x) for x in v]  # noqa: E731
        return {"nominal_min": f(self.nominal_min), "nominal_max": f(self.nominal_max),
                "nominal_speed": f(self.nominal_speed), "worst_min": f(self.worst_min),
                "worst_max": f(self.worst_max), "worst_speed": f(self.worst_speed),
                "units": {"position": "rad", "speed": "rad/s"}}

    @classmethod
    def from_dict(cls, d: dict) -> "Excursion":
        g = lambda k: [float(x) for x in d.get(k, [])]  # noqa: E731
        return cls(g("nominal_min"), g("nominal_max"), g("nominal_speed"), g("worst_min"),
                   g("worst_max"), g("worst_speed"))

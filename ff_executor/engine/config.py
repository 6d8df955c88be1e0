"""The executor's settings (:class:`EngineConfig`), its refusal (:class:`ProfileRejected`) and ``NS``.

Units: s (float) and ns (integer, ``*_ns``), A, rad, rad/s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

NS = 1_000_000_000
"""Nanoseconds per second."""


class ProfileRejected(ValueError):
    """A profile (or the arm's state) the executor refuses to run; the message says what to change."""


@dataclass(frozen=True)
class EngineConfig:
    """What the executor accepts and how it streams.

    joint_names:    joints of the drive group, in the bridge's order (setpoint currents follow it).
    current_limits: A, per joint; a profile above them is refused (the bridge clamps as well).
    lead_time:      s, each setpoint is published this long before its stamp.
    start_margin:   s, start = now + start_margin when no start time is requested (>= lead_time).
    max_start_wait: s, a requested start further ahead than this is refused.
    max_steps:      most current steps per joint accepted.
    min_step:       s, shortest step accepted (the drive cannot switch faster than its cycle).
    max_move_time:  s, longest tf accepted.
    keepalive:      s, re-send the present current at this period between switches (feeds the
                    bridge's setpoint watchdog); 0 = one setpoint per switch only.
    start_tolerance: rad, the arm must be within this of the profile's q0 before the move
                    (a feedforward move is relative: starting elsewhere shifts the goal); inf = off.
    rest_velocity:  rad/s, |velocity| below this counts as at rest (start check, settling).
    """

    joint_names: tuple[str, ...] = ("joint1",)
    current_limits: tuple[float, ...] = (10.0,)
    lead_time: float = 0.1
    start_margin: float = 0.25
    max_start_wait: float = 60.0
    max_steps: int = 10_000
    min_step: float = 1e-4
    max_move_time: float = 600.0
    keepalive: float = 0.0
    start_tolerance: float = 0.02
    rest_velocity: float = 1e-3

    def __post_init__(self) -> None:
        object.__setattr__(self, "joint_names", tuple(str(n) for n in self.joint_names))
        object.__setattr__(self, "current_limits", tuple(float(x) for x in self.current_limits))
        if not self.joint_names:
            raise ValueError("executor needs at least one joint name (parameter joint_names)")
        if len(set(self.joint_names)) != len(self.joint_names):
            raise ValueError(f"joint names repeat: {list(self.joint_names)}")
        if len(self.current_limits) == 1 and len(self.joint_names) > 1:
            object.__setattr__(self, "current_limits", self.current_limits * len(self.joint_names))
        if len(self.current_limits) != len(self.joint_names):
            raise ValueError(f"{len(self.current_limits)} current limits for {len(self.joint_names)} "
                             "joints: give one per joint (or one for all)")
        if not all(math.isfinite(x) and x > 0 for x in self.current_limits):
            raise ValueError(f"current limits must be finite and > 0 A, got {list(self.current_limits)}")
        for name in ("lead_time", "start_margin", "max_start_wait", "min_step", "max_move_time",
                     "keepalive", "rest_velocity"):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be finite and >= 0 s, got {v}")
        if self.start_margin < self.lead_time:
            raise ValueError(f"start_margin ({self.start_margin} s) must be >= lead_time "
                             f"({self.lead_time} s), or the first setpoint would be late")
        if self.max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {self.max_steps}")
        if math.isnan(self.start_tolerance) or self.start_tolerance <= 0:
            raise ValueError("start_tolerance must be > 0 rad (use inf to switch the check off)")

    @property
    def n_joints(self) -> int:
        """Number of joints of the drive group."""
        return len(self.joint_names)

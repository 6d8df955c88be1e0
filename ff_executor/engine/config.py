"""The executor's parameters (:data:`EXECUTOR_PARAMETERS`, the single source of their defaults,
units, ranges and descriptions), its settings (:class:`EngineConfig`), its refusal
(:class:`ProfileRejected`) and ``NS``.

The ROS node declares its parameters from :data:`EXECUTOR_PARAMETERS`; ``config/executor.yaml``
and the table in ``docs/parameters.md`` are written from it (``python -m
ff_executor.engine.paramgen``). Units: s (float) and ns (integer, ``*_ns``), A, rad, rad/s, Hz.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Mapping

from ff_executor.engine.paramspec import ParamSpec, ParamTable

NS = 1_000_000_000
"""Nanoseconds per second."""

INF = math.inf

#: Every parameter of the ``ff_executor`` node. ``read_at_start`` ones configure the engine
#: (:class:`EngineConfig`) or a subscription when the node starts; the others are read for each goal.
EXECUTOR_PARAMETERS = ParamTable("ff_executor", (
    ParamSpec("joint_names", ("joint1",), "", "joints of the drive group, in the bridge's order"),
    ParamSpec("current_limits", (10.0,), "A",
              "per joint (one value = all joints); profiles above are refused (the bridge clamps too)"),
    ParamSpec("lead_time", 0.1, "s", "publish each setpoint this long before its stamp", (0.0, 10.0)),
    ParamSpec("start_margin", 0.25, "s",
              "start this long after the goal when it gives no start time (>= lead_time)", (0.0, 60.0)),
    ParamSpec("max_start_wait", 60.0, "s", "refuse start times further ahead", (0.0, 86400.0)),
    ParamSpec("max_steps", 10000, "", "most current steps per joint", (1, 10_000_000)),
    ParamSpec("min_step", 1e-4, "s", "shortest current step accepted", (0.0, 10.0)),
    ParamSpec("max_move_time", 600.0, "s", "longest move accepted", (0.0, 86400.0)),
    ParamSpec("keepalive", 0.25, "s",
              "repeat the present current at this period between switches; keep it below the "
              "bridge's setpoint watchdog (setpoint_timeout, 0.5 s); 0 = switches only, which "
              "trips that watchdog on a step longer than it", (0.0, 60.0)),
    ParamSpec("start_tolerance", 0.02, "rad",
              "the arm must be at rest this close to the profile's q0 (inf = no check)", (0.0, INF)),
    ParamSpec("rest_velocity", 1e-3, "rad/s", "at rest below this (start check, settling)", (0.0, 100.0)),
    ParamSpec("settle_hold", 0.05, "s", "at rest this long = settled", (0.0, 60.0), read_at_start=False),
    ParamSpec("settle_timeout", 3.0, "s", "after tf, give up waiting for rest", (0.0, 3600.0),
              read_at_start=False),
    ParamSpec("feedback_rate", 20.0, "Hz", "action feedback rate (at least 10 Hz is sent)", (0.0, 1000.0),
              read_at_start=False),
    ParamSpec("bridge_node", "ff_hwbridge", "", "name of the bridge lifecycle node"),
    ParamSpec("require_bridge_active", True, "",
              "refuse goals unless the bridge reports lifecycle state active", read_at_start=False),
    ParamSpec("bridge_timeout", 5.0, "s", "wait this long for the bridge's get_state service", (0.0, 600.0),
              read_at_start=False),
    ParamSpec("setpoint_topic", "/ff_hwbridge/setpoints", "", "where setpoints go (ff_msgs/msg/CurrentSetpoint)"),
    ParamSpec("joint_state_topic", "/ff_hwbridge/joint_states", "",
              "measured joint states (sensor_msgs/msg/JointState)"),
    ParamSpec("current_topic", "/ff_hwbridge/motor_currents", "",
              "measured motor currents (sensor_msgs/msg/JointState, effort A) for the switch-time "
              "estimate; '' = the joint states' effort"),
    ParamSpec("applied_topic", "/ff_hwbridge/applied", "", "the bridge's reports of applied setpoints (optional)"),
    ParamSpec("joint_state_timeout", 1.0, "s", "stop the move (zero current, abort) if joint states stop this long",
              (0.0, 600.0), read_at_start=False),
    ParamSpec("refuse_mode", "abort", "",
              "'abort': accept a refused goal, then abort it with the reason; 'reject': reject it "
              "(the reason goes to the node's log only)", choices=("abort", "reject"), read_at_start=False),
))

_D = EXECUTOR_PARAMETERS.default


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

    joint_names: tuple[str, ...] = _D("joint_names")
    current_limits: tuple[float, ...] = _D("current_limits")
    lead_time: float = _D("lead_time")
    start_margin: float = _D("start_margin")
    max_start_wait: float = _D("max_start_wait")
    max_steps: int = _D("max_steps")
    min_step: float = _D("min_step")
    max_move_time: float = _D("max_move_time")
    keepalive: float = _D("keepalive")
    start_tolerance: float = _D("start_tolerance")
    rest_velocity: float = _D("rest_velocity")

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

    @classmethod
    def from_parameters(cls, values: Mapping[str, Any]) -> EngineConfig:
        """The configuration from parameter values by name (others are ignored; missing ones keep
        their defaults)."""
        kinds = {"joint_names": tuple, "current_limits": tuple, "max_steps": int}
        kwargs = {f.name: kinds.get(f.name, float)(values[f.name]) for f in fields(cls) if f.name in values}
        return cls(**kwargs)

    @property
    def n_joints(self) -> int:
        """Number of joints of the drive group."""
        return len(self.joint_names)

"""A current profile as a ``trajectory_msgs/JointTrajectory`` of joint torques, for ros2_control users.

``profile_to_joint_trajectory(profile, torque_constant, gear_ratio)`` turns an
``ff_msgs/CurrentProfile`` (or the planner's ``CurrentProfile`` with ``joint_names``) into points
whose ``effort`` is the joint torque in N·m (REP 103): ``effort = current (A) × torque_constant
(N·m/A, at the motor) × gear_ratio`` per joint, the torque the planner's model applies at the joint
(``n · kt · I``). A controller interpolates linearly between points, so every current switch is
written as two points ``switch_epsilon`` apart (the old torque just before it, the new one at
it): the interpolated command is then the profile's steps, ramps only ``switch_epsilon`` long. The
last points hold zero torque from the end of the last step (tf − coast) to tf. ``state_at(t)``
(optional, t in s from the start) fills ``positions`` (rad) and ``velocities`` (rad/s) of every
point, e.g. from the planner's nominal simulation, for controllers that need them.

Timing caveat: the plan is robust to friction, not to switch timing. A JointTrajectoryController
samples the trajectory at its update rate, so each switch takes effect at the first control cycle
after it: up to one update period late (1 ms at 1 kHz; the certificate's ``switch_timing`` says
how many rad of rest error 100 µs of delay costs), plus the latency of a topic-based hardware
interface (a DDS message per cycle, not time-stamped). Its effort command interface also closes
a PID loop on the position/velocity error of the points rather than forwarding ``effort`` — for a
feedforward replay use a controller that forwards the points' effort, or the suite's executor,
which stamps each setpoint and lets the drive apply it at its SYNC.
"""
from __future__ import annotations

from typing import Any, Callable, Optional, Sequence, Union

import numpy as np
from builtin_interfaces.msg import Duration
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from ff_msgs_py.convert import msg_to_profile, ns_to_time
from ff_planner.model.profile import CurrentProfile

Number = Union[float, Sequence[float]]
StateAt = Callable[[float], tuple[Sequence[float], Sequence[float]]]
SWITCH_EPSILON = 1e-6     # s between the two points written at a current switch


def _per_joint(name: str, value: Number, nj: int) -> np.ndarray:
    v = np.broadcast_to(np.asarray(value, dtype=float).ravel(), (nj,)) if np.size(value) in (1, nj) else None
    if v is None or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} needs 1 or {nj} finite value(s), got {value!r}")
    return np.array(v)


def duration(seconds: float) -> Duration:
    """builtin_interfaces/Duration of ``seconds`` (>= 0), to the nanosecond."""
    ns = int(round(float(seconds) * 1e9))
    if ns < 0:
        raise ValueError(f"time from start must be >= 0 s, got {seconds}")
    return Duration(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def profile_to_joint_trajectory(profile: Any, torque_constant: Number, gear_ratio: Number = 1.0, *,
                                joint_names: Optional[Sequence[str]] = None,
                                switch_epsilon: float = SWITCH_EPSILON, start_ns: int = 0,
                                state_at: Optional[StateAt] = None) -> JointTrajectory:
    """The profile as a JointTrajectory of joint torques (N·m); see the module docstring.

    profile: ``ff_msgs/CurrentProfile`` or ``CurrentProfile`` (then ``joint_names`` is required).
    torque_constant: N·m/A per joint (or one for all); gear_ratio: joint torque per motor torque.
    switch_epsilon (s): gap between the two points of a switch, below the shortest step.
    start_ns: ``header.stamp`` (ROS time, ns; 0 = start on receipt).
    """
    if isinstance(profile, CurrentProfile):
        prof = profile
        if joint_names is None:
            raise ValueError("joint_names are needed for a CurrentProfile dataclass")
        names = [str(n) for n in joint_names]
    else:
        prof = msg_to_profile(profile)
        names = [str(n) for n in (joint_names if joint_names is not None else profile.joint_names)]
    nj = prof.n_joints
    if len(names) != nj:
        raise ValueError(f"{len(names)} joint names for a {nj}-joint profile")
    gain = _per_joint("torque_constant", torque_constant, nj) * _per_joint("gear_ratio", gear_ratio, nj)
    times = np.asarray(prof.step_times, dtype=float)
    shortest = float(np.min(np.diff(times))) if times.size > 1 else 0.0
    if not 0.0 < switch_epsilon < shortest / 2:
        raise ValueError(f"switch_epsilon must be in (0, {shortest / 2:.3g}) s (half the shortest step), "
                         f"got {switch_epsilon}")
    torque = prof.currents * gain.reshape(1, -1)            # N·m, steps × joints
    zero = np.zeros(nj)
    points: list[tuple[float, np.ndarray]] = [(float(times[0]), torque[0])]
    for i in range(1, prof.n_steps + 1):
        after = torque[i] if i < prof.n_steps else zero
        points.append((float(times[i]) - switch_epsilon, torque[i - 1]))
        points.append((float(times[i]), after))
    if prof.tf > times[-1] + switch_epsilon:
        points.append((float(prof.tf), zero))
    out = JointTrajectory(joint_names=names)
    out.header.stamp = ns_to_time(start_ns)
    for t, effort in points:
        pt = JointTrajectoryPoint(effort=[float(x) for x in effort], time_from_start=duration(t))
        if state_at is not None:
            q, qd = state_at(t)
            pt.positions = [float(x) for x in q]
            pt.velocities = [float(x) for x in qd]
        out.points.append(pt)
    return out


def effort_at(trajectory: Any, t: Union[float, Sequence[float], np.ndarray]) -> np.ndarray:
    """The effort (N·m per joint) a controller interpolating linearly between the points commands
    ``t`` s after the start (the first point's before it, the last one's after it): shape
    (joints,) for one time, (len(t), joints) for several."""
    ts = np.array([p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec for p in trajectory.points])
    ef = np.array([list(p.effort) for p in trajectory.points], dtype=float)
    tt = np.asarray(t, dtype=float)
    out = np.stack([np.interp(tt.ravel(), ts, ef[:, j]) for j in range(ef.shape[1])], axis=-1)
    return out[0] if tt.ndim == 0 else out

"""Checks before anything moves: the profile (:func:`check_profile`), the arm's state
(:func:`check_start_state`) and the start time (:func:`resolve_start`).

Each refuses with :class:`ProfileRejected`, whose message says what to change.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike

from ff_executor.engine.config import NS, EngineConfig, ProfileRejected
from ff_planner.model.profile import CurrentProfile


@dataclass
class Motion:
    """A checked profile ready to stream: currents in the bridge's joint order."""

    profile: CurrentProfile
    profile_id: str
    joint_names: tuple[str, ...]
    q0: np.ndarray   # rad
    qf: np.ndarray   # rad


def check_profile(profile: CurrentProfile, joint_names: Sequence[str], q0: ArrayLike,
                  qf: ArrayLike, config: EngineConfig, profile_id: str = "") -> Motion:
    """Check a profile before anything moves; return it reordered to the bridge's joints.

    Raises ProfileRejected naming what to change: joint names unknown or missing, step times not
    finite / not starting at 0 / not increasing / past tf − coast, steps shorter than min_step,
    too many steps, currents beyond the limits, q0/qf of the wrong length.
    """
    names = [str(n) for n in joint_names]
    if sorted(names) != sorted(config.joint_names) or len(set(names)) != len(names):
        raise ProfileRejected(f"profile joints {names} do not match this executor's joints "
                              f"{list(config.joint_names)}; plan for the same joints")
    nj = len(names)
    if profile.currents.ndim != 2 or profile.n_joints != nj:
        raise ProfileRejected(f"profile has currents for {profile.n_joints} joint(s) but names "
                              f"{nj} joint(s)")
    if profile.n_steps < 1:
        raise ProfileRejected("profile has no current steps (n_steps = 0)")
    if profile.n_steps > config.max_steps:
        raise ProfileRejected(f"profile has {profile.n_steps} steps; this executor accepts at most "
                              f"{config.max_steps} (parameter max_steps)")
    q0a = np.asarray(q0, dtype=float).reshape(-1)
    qfa = np.asarray(qf, dtype=float).reshape(-1)
    for label, arr in (("q0", q0a), ("qf", qfa)):
        if arr.size != nj:
            raise ProfileRejected(f"profile {label} has {arr.size} value(s) for {nj} joint(s)")
        if not np.all(np.isfinite(arr)):
            raise ProfileRejected(f"profile {label} must be finite, got {arr.tolist()}")
    try:
        profile.validate()
    except ValueError as exc:
        raise ProfileRejected(f"bad profile: {exc}") from None
    if not math.isfinite(profile.tf) or profile.tf <= 0 or profile.tf > config.max_move_time:
        raise ProfileRejected(f"move time {profile.tf} s must be in (0, {config.max_move_time}] s "
                              "(parameter max_move_time)")
    shortest = float(np.min(np.diff(profile.step_times)))
    if shortest < config.min_step:
        raise ProfileRejected(f"a current step lasts {shortest * 1e3:.4g} ms; the shortest this "
                              f"executor accepts is {config.min_step * 1e3:.4g} ms (parameter min_step)")
    order = [names.index(n) for n in config.joint_names]
    currents = profile.currents[:, order]
    limits = np.asarray(config.current_limits)
    over = np.abs(currents) > limits[None, :] + 1e-9
    if np.any(over):
        i, j = np.argwhere(over)[0]
        raise ProfileRejected(f"step {i} asks {currents[i, j]:.4g} A on {config.joint_names[j]}, "
                              f"beyond its limit of {limits[j]:.4g} A; re-plan within the limit")
    reordered = CurrentProfile(profile.step_times.copy(), currents, profile.tf, profile.coast)
    return Motion(reordered, profile_id, config.joint_names, q0a[order], qfa[order])


def check_start_state(positions: Optional[ArrayLike], velocities: Optional[ArrayLike],
                      motion: Motion, config: EngineConfig) -> None:
    """Refuse to start unless the arm is at rest near the profile's q0 (ProfileRejected)."""
    if positions is None:
        raise ProfileRejected("no joint state received from the bridge yet; is it running "
                              "and publishing joint_states?")
    pos = np.asarray(positions, dtype=float)
    vel = np.asarray(velocities if velocities is not None else np.zeros_like(pos), dtype=float)
    if math.isfinite(config.start_tolerance):
        off = pos - motion.q0
        if np.any(np.abs(off) > config.start_tolerance):
            raise ProfileRejected(f"arm is at {np.round(pos, 5).tolist()} rad but the profile starts "
                                  f"at {motion.q0.tolist()} rad (tolerance {config.start_tolerance} "
                                  "rad); move the arm to q0 first")
    if np.any(np.abs(vel) > max(config.rest_velocity, 1e-12)):
        raise ProfileRejected(f"arm is moving ({np.round(vel, 5).tolist()} rad/s); wait until it "
                              "is at rest")


def resolve_start(requested_ns: int, now_ns: int, config: EngineConfig) -> int:
    """Start time (ns) of step 0: ``requested_ns`` 0 = now + start_margin.

    A requested start that leaves less than the lead time is moved to now + start_margin (the
    result reports the delay; a common delay of the whole profile is harmless); one further
    ahead than max_start_wait is refused.
    """
    earliest = now_ns + int(round(config.start_margin * NS))
    if requested_ns <= 0:
        return earliest
    if requested_ns - now_ns > config.max_start_wait * NS:
        raise ProfileRejected(f"start time is {(requested_ns - now_ns) / NS:.3g} s ahead; at most "
                              f"{config.max_start_wait} s is accepted (parameter max_start_wait)")
    if requested_ns < now_ns + int(round(config.lead_time * NS)):
        return earliest
    return int(requested_ns)


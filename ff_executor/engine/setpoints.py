"""Stamped setpoints: a checked motion turned into timed current commands.

Each :class:`Setpoint` carries the moment (``stamp_ns``, ROS clock) its currents take effect; the
bridge applies it then, so the relative timing of the current switches is fixed by the stamps.
"""
from __future__ import annotations

from dataclasses import dataclass

from ff_executor.engine.checks import Motion
from ff_executor.engine.config import NS


@dataclass(frozen=True)
class Setpoint:
    """One timed current command: ``currents`` (A, per joint) take effect at ``stamp_ns``."""

    stamp_ns: int
    currents: tuple[float, ...]
    seq: int
    profile_id: str = ""
    last: bool = False
    switch: bool = True     # False for keep-alive repeats of an unchanged current


def build_setpoints(motion: Motion, start_ns: int, keepalive: float = 0.0) -> list[Setpoint]:
    """The stamped setpoint sequence of a motion starting at ``start_ns`` (ns, ROS clock).

    One setpoint per current switch (consecutive equal steps merge), the final zero at
    start + step_times[-1] (= tf − coast) marked ``last``; with ``keepalive`` > 0 s the present
    current is repeated at that period in between (``switch=False``).
    """
    prof = motion.profile
    times = [start_ns + int(round(float(t) * NS)) for t in prof.step_times]
    segments: list[tuple[int, tuple[float, ...]]] = []       # (stamp, currents) at each switch
    for i in range(prof.n_steps):
        cur = tuple(float(c) for c in prof.currents[i])
        if not segments or segments[-1][1] != cur:
            segments.append((times[i], cur))
    zero = tuple(0.0 for _ in range(prof.n_joints))
    ends = [s[0] for s in segments[1:]] + [times[-1]]
    period = int(round(keepalive * NS)) if keepalive > 0 else 0
    out: list[Setpoint] = []
    for (stamp, cur), end in zip(segments, ends):
        out.append(Setpoint(stamp, cur, len(out), motion.profile_id))
        t = stamp + period
        while period and t < end - period // 4:
            out.append(Setpoint(t, cur, len(out), motion.profile_id, switch=False))
            t += period
    out.append(Setpoint(times[-1], zero, len(out), motion.profile_id, last=True,
                        switch=segments[-1][1] != zero))
    return out

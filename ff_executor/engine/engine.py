"""The executor's streaming engine (no ROS): profile checks, stamped setpoints, streaming, timing.

A feedforward profile only works if every current switch happens at the right moment *relative to
the others* (DESIGN.md: 1 ms at 10 A moves the paper's arm by ~0.04 rad). So the executor never
decides *when* a current takes effect: it turns the profile into setpoints that carry the time
they must take effect (``stamp``, ROS clock, ns) and hands each to the bridge ``lead_time``
seconds early; the bridge, nearest the bus, applies each at its stamp.

Pieces (all plain functions / dataclasses, driven by an injected clock so tests run instantly):

- :func:`check_profile`  — refuse a profile before anything moves (limits, times, joint names).
- :func:`build_setpoints` — one setpoint per current switch, plus the final zero at tf − coast
  (``last=True``), optionally keep-alive repeats of the current value.
- :class:`Stream`          — which setpoints are due for publishing at a given time; cancel → zero.
- :class:`StreamRunner`    — the publishing loop (sleep/clock/publish injected) with a tick hook
  for feedback and a cancel check.
- :class:`SettleDetector`  — decides when the arm has come to rest after the move.
- :func:`timing_stats` / :func:`estimate_applied_times` — switch-time error statistics from the
  bridge's reports of applied times, or estimated from measured currents.

Units: s and ns (integers, ``*_ns``), A, rad, rad/s.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Iterable, Optional, Sequence

import numpy as np

from ff_planner.model.profile import CurrentProfile

NS = 1_000_000_000


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
        return len(self.joint_names)


@dataclass
class Motion:
    """A checked profile ready to stream: currents in the bridge's joint order."""

    profile: CurrentProfile
    profile_id: str
    joint_names: tuple[str, ...]
    q0: np.ndarray   # rad
    qf: np.ndarray   # rad


def check_profile(profile: CurrentProfile, joint_names: Sequence[str], q0: Sequence[float],
                  qf: Sequence[float], config: EngineConfig, profile_id: str = "") -> Motion:
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


def check_start_state(positions: Optional[Sequence[float]], velocities: Optional[Sequence[float]],
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


@dataclass
class Published:
    setpoint: Setpoint
    published_ns: int


class Stream:
    """Which setpoints to publish when: each at ``stamp - lead``; cancel → an immediate zero."""

    def __init__(self, setpoints: Sequence[Setpoint], lead_time: float) -> None:
        if not setpoints:
            raise ValueError("nothing to stream: empty setpoint list")
        stamps = [s.stamp_ns for s in setpoints]
        if any(b < a for a, b in zip(stamps, stamps[1:])):
            raise ValueError("setpoint stamps must not decrease")
        self.setpoints = list(setpoints)
        self.lead_ns = int(round(lead_time * NS))
        self.published: list[Published] = []
        self._next = 0
        self.cancelled = False
        self.extra: list[Setpoint] = []      # setpoints sent on cancel
        self.override_ns = 1000              # a cancel zero follows each pending stamp by 1 µs

    @property
    def done(self) -> bool:
        """True when nothing is left to publish (all sent, or cancelled)."""
        return self.cancelled or self._next >= len(self.setpoints)

    @property
    def start_ns(self) -> int:
        return self.setpoints[0].stamp_ns

    @property
    def end_ns(self) -> int:
        """Stamp of the final (zero) setpoint."""
        return self.setpoints[-1].stamp_ns

    def next_publish_ns(self) -> Optional[int]:
        """When the next setpoint is due for publishing (ns), None if none is left."""
        if self.done:
            return None
        return self.setpoints[self._next].stamp_ns - self.lead_ns

    def due(self, now_ns: int) -> list[Setpoint]:
        """Setpoints due at ``now_ns`` (stamp − lead <= now), marked as published, in order."""
        out = []
        while not self.done and self.setpoints[self._next].stamp_ns - self.lead_ns <= now_ns:
            sp = self.setpoints[self._next]
            self.published.append(Published(sp, now_ns))
            out.append(sp)
            self._next += 1
        return out

    def late(self) -> list[Published]:
        """Setpoints published after their stamp (the bridge got them too late)."""
        return [p for p in self.published if p.published_ns > p.setpoint.stamp_ns]

    def commanded(self, now_ns: int) -> tuple[float, ...]:
        """Currents (A) in force at ``now_ns`` by the plan (zero before start and after the end)."""
        zero = tuple(0.0 for _ in self.setpoints[0].currents)
        if self.cancelled and self.extra and self.extra[0].stamp_ns <= now_ns:
            return zero
        cur = zero
        for sp in self.setpoints[: self._next]:
            if sp.stamp_ns <= now_ns:
                cur = sp.currents
        return cur

    def cancel(self, now_ns: int) -> list[Setpoint]:
        """Stop: setpoints to publish at once, all zero current and marked ``last``.

        The first is stamped ``now_ns``. Setpoints already handed to the bridge with later stamps
        would still take effect there (a bridge need not drop its queue), so each of them gets a
        zero stamped ``override`` (1 µs) after it: whatever the bridge does with its queue, any
        current it still applies lasts only until the next frame.
        """
        if self.cancelled:
            return []
        self.cancelled = True
        nj = len(self.setpoints[0].currents)
        zero = tuple(0.0 for _ in range(nj))
        seq = len(self.setpoints)
        pid = self.setpoints[0].profile_id
        out = [Setpoint(now_ns, zero, seq, pid, last=True)]
        pending = sorted({p.setpoint.stamp_ns for p in self.published
                          if p.setpoint.stamp_ns >= now_ns and any(p.setpoint.currents)})
        for k, stamp in enumerate(pending, start=1):
            out.append(Setpoint(stamp + self.override_ns, zero, seq + k, pid, last=True))
        for sp in out:
            self.published.append(Published(sp, now_ns))
        self.extra = out
        return out

    def all_sent(self) -> list[Setpoint]:
        return [p.setpoint for p in self.published]


@dataclass
class StreamRunner:
    """The publishing loop: publish due setpoints, call ``on_tick`` every ``tick_period`` s.

    ``clock_ns`` is the ROS clock, ``sleep`` sleeps seconds, ``should_cancel`` is polled; the loop
    returns when every setpoint is published and the clock has passed ``until_ns`` (default: the
    final stamp), or after a cancel (its zero setpoints published). Returns True if cancelled.
    """

    stream: Stream
    publish: Callable[[Setpoint], None]
    clock_ns: Callable[[], int]
    sleep: Callable[[float], None] = time.sleep
    should_cancel: Callable[[], bool] = lambda: False
    on_tick: Optional[Callable[[int], None]] = None
    tick_period: float = 0.05
    max_sleep: float = 0.01

    def run(self, until_ns: Optional[int] = None) -> bool:
        until = self.stream.end_ns if until_ns is None else int(until_ns)
        tick_ns = int(round(self.tick_period * NS))
        next_tick = self.clock_ns()
        while True:
            now = self.clock_ns()
            if self.should_cancel():
                for sp in self.stream.cancel(now):
                    self.publish(sp)
                if self.on_tick is not None:
                    self.on_tick(now)
                return True
            for sp in self.stream.due(now):
                self.publish(sp)
            if self.on_tick is not None and now >= next_tick:
                self.on_tick(now)
                next_tick = max(next_tick + tick_ns, now - tick_ns)
            if self.stream.done and now >= until:
                return False
            wake = [until, next_tick if self.on_tick is not None else until]
            nxt = self.stream.next_publish_ns()
            if nxt is not None:
                wake.append(nxt)
            wait = (min(wake) - self.clock_ns()) / NS
            self.sleep(min(max(wait, 0.0), self.max_sleep))


@dataclass
class SettleDetector:
    """The arm has settled when every |velocity| <= ``velocity`` (rad/s) for ``hold`` s."""

    velocity: float = 1e-3
    hold: float = 0.05
    _since: Optional[int] = field(default=None, repr=False)

    def update(self, t_ns: int, velocities: Sequence[float]) -> bool:
        if np.all(np.abs(np.asarray(velocities, dtype=float)) <= self.velocity):
            if self._since is None:
                self._since = t_ns
            return t_ns - self._since >= int(round(self.hold * NS))
        self._since = None
        return False


@dataclass
class TimingStats:
    """Switch-time error |applied − stamp| over the current switches of one motion (s)."""

    count: int = 0
    p50: float = math.nan
    p99: float = math.nan
    max: float = math.nan
    source: str = "none"          # "bridge" (reported applied times), "estimated", or "none"

    def as_dict(self) -> dict:
        return {"count": self.count, "p50": self.p50, "p99": self.p99, "max": self.max,
                "source": self.source}


def timing_stats(stamps_ns: Iterable[int], applied_ns: Iterable[int], source: str) -> TimingStats:
    """Statistics of |applied − stamp| (s) for matched pairs; NaN figures when there are none."""
    err = np.abs(np.asarray(list(applied_ns), dtype=float) - np.asarray(list(stamps_ns), dtype=float)) / NS
    if err.size == 0:
        return TimingStats(source="none")
    return TimingStats(int(err.size), float(np.percentile(err, 50)), float(np.percentile(err, 99)),
                       float(err.max()), source)


def estimate_applied_times(setpoints: Sequence[Setpoint], sample_ns: Sequence[int],
                           measured: Sequence[Sequence[float]], window: float = 0.02
                           ) -> list[tuple[int, int]]:
    """Estimate when each current switch took effect from measured currents (A) at ``sample_ns``.

    For each switching setpoint: the first sample no earlier than ``stamp − window`` whose
    current is nearer the new value than the old one (all joints). Returns (stamp, estimate)
    pairs; the estimate is an upper bound quantised by the sample period, so use it only when
    the bridge does not report applied times.
    """
    t = np.asarray(sample_ns, dtype=np.int64)
    if t.size == 0:
        return []
    m = np.asarray(measured, dtype=float).reshape(t.size, -1)
    order = np.argsort(t, kind="stable")
    t, m = t[order], m[order]
    pairs: list[tuple[int, int]] = []
    prev = np.zeros(m.shape[1])
    win = int(round(window * NS))
    switches = [s for s in setpoints if s.switch]
    for k, sp in enumerate(switches):
        new = np.asarray(sp.currents, dtype=float)
        if np.allclose(new, prev):
            continue
        limit = switches[k + 1].stamp_ns if k + 1 < len(switches) else sp.stamp_ns + 10 * win
        lo = int(np.searchsorted(t, sp.stamp_ns - win, side="left"))
        hi = int(np.searchsorted(t, limit, side="left"))
        for i in range(lo, hi):
            if np.all(np.abs(m[i] - new) < np.abs(m[i] - prev)):
                pairs.append((sp.stamp_ns, int(t[i])))
                break
        prev = new
    return pairs

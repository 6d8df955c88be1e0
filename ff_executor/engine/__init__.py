"""The executor's streaming engine (no ROS): profile checks, stamped setpoints, streaming, timing.

A feedforward profile only works if every current switch happens at the right moment *relative to
the others* (at 10 A, a switch 1 ms off moves the paper's arm by ~0.04 rad). So the executor never
decides *when* a current takes effect: it turns the profile into setpoints that carry the time
they must take effect (``stamp``, ROS clock, ns) and hands each to the bridge ``lead_time``
seconds early; the bridge, nearest the bus, applies each at its stamp.

Modules (plain functions / dataclasses, driven by an injected clock so tests run instantly):

- :mod:`.config`    — :class:`EngineConfig` (limits, lead time, ...), :class:`ProfileRejected`, ``NS``.
- :mod:`.checks`    — :func:`check_profile`, :func:`check_start_state`, :func:`resolve_start`:
  refuse a profile, an arm state or a start time before anything moves; :class:`Motion`.
- :mod:`.setpoints` — :func:`build_setpoints`: one :class:`Setpoint` per current switch, plus the
  final zero at tf − coast (``last=True``), optionally keep-alive repeats of the current value.
- :mod:`.stream`    — :class:`Stream` (which setpoints are due at a given time; cancel → zero) and
  :class:`StreamRunner` (the publishing loop, with a tick hook for feedback and a cancel check).
- :mod:`.settle`    — :class:`SettleDetector`: when the arm has come to rest after the move.
- :mod:`.timing`    — :func:`timing_stats` / :func:`estimate_applied_times`: switch-time error
  statistics from the bridge's reports of applied times, or estimated from measured currents;
  :func:`missed_cycles`: SYNC cycles lost by setpoints that took effect late.

Units: s and ns (integers, ``*_ns``), A, rad, rad/s.
"""
from ff_executor.engine.checks import Motion, check_profile, check_start_state, resolve_start
from ff_executor.engine.config import NS, EngineConfig, ProfileRejected
from ff_executor.engine.setpoints import Setpoint, build_setpoints
from ff_executor.engine.settle import SettleDetector
from ff_executor.engine.stream import Published, Stream, StreamRunner
from ff_executor.engine.timing import TimingStats, estimate_applied_times, missed_cycles, timing_stats

__all__ = [
    "NS",
    "EngineConfig",
    "Motion",
    "ProfileRejected",
    "Published",
    "Setpoint",
    "SettleDetector",
    "Stream",
    "StreamRunner",
    "TimingStats",
    "build_setpoints",
    "check_profile",
    "check_start_state",
    "estimate_applied_times",
    "missed_cycles",
    "resolve_start",
    "timing_stats",
]

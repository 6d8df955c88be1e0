"""Streaming: which setpoints are due when (:class:`Stream`) and the publishing loop
(:class:`StreamRunner`).

Each setpoint is published ``lead_time`` s before its stamp; a cancel publishes zero current at
once. The clock, sleep and publish functions are injected, so tests run on a fake clock.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

from ff_executor.engine.config import NS
from ff_executor.engine.setpoints import Setpoint


@dataclass
class Published:
    """A setpoint and the moment (ns, ROS clock) it was handed to the publisher."""

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
        """Stamp of the first setpoint (ns)."""
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
        """Every setpoint published so far, cancel zeros included, in publishing order."""
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
        """Stream until done (see the class docstring); True if cancelled."""
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

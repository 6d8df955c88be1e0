"""Stamped current setpoints played onto the drives: setpoint → safety guard → units → RPDO at its
stamp.

:class:`SetpointPlayer` composes the three parts of the drive layer that every stamped setpoint
goes through:

1. ``submit(stamp_ns, currents_A)`` feeds the setpoint watchdog (a motion runs after a profile's
   setpoint that is not its last, or after a manual setpoint with a non-zero current; a manual
   zero ends it) and queues the setpoint on a :class:`~ff_hwbridge.drive.scheduler.StampScheduler`.
2. Shortly before the stamp (``spin_margin`` s) the scheduler thread runs
   ``EposMaster.prepare_currents``: the :class:`~ff_hwbridge.drive.safety.SafetyGuard` (clamp to
   ±limit A, NaN/inf → 0 A, 0 A while latched) and the conversion to raw drive units.
3. At the stamp it sends the prepared RPDOs (``EposMaster.send_prepared``) and records
   sent − stamp for the switch-time statistics; the setpoint is reported as an
   :class:`AppliedSetpoint` (``take_applied()``).

A latched safe state drops every pending setpoint; ``stop()`` drops them, stops the thread and
commands zero current. Stamps are integer ns on ``clock_ns`` (default ``time.time_ns``, the ROS
system clock).
"""
from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

from ff_hwbridge.drive.config import BridgeConfig
from ff_hwbridge.drive.epos import EposMaster, PreparedCommand
from ff_hwbridge.drive.scheduler import StampScheduler, SwitchStats

__all__ = ["AppliedSetpoint", "PlayerConfig", "SetpointPlayer", "SetpointRejected"]


class SetpointRejected(ValueError):
    """A setpoint the player does not queue (wrong number of currents, safe state latched)."""


LATE_THRESHOLD = 0.0005   # s: a setpoint sent more than this after its stamp counts as late
MAX_RECORDS = 200_000     # (stamp, sent) pairs the statistics keep
MAX_REPORTS = 10_000      # applied setpoints waiting for ``take_applied()`` (oldest dropped)


@dataclass(frozen=True)
class PlayerConfig:
    """Timing of the player's scheduler thread.

    spin_margin:    s, the thread sleeps until this long before a stamp, then spins.
    rt_priority:    1..99: SCHED_FIFO for the thread (needs CAP_SYS_NICE); 0 = normal.
    prepare_ahead:  guard + unit conversion before the stamp (True) or at it, together with the
                    send (False: a little later, for measuring what the early step gains).
    """

    spin_margin: float = 0.0003
    rt_priority: int = 0
    prepare_ahead: bool = True

    @classmethod
    def from_bridge(cls, config: BridgeConfig) -> "PlayerConfig":
        """The timing of a bridge configuration (``spin_margin``, ``scheduler_rt_priority``)."""
        return cls(spin_margin=config.spin_margin, rt_priority=config.scheduler_rt_priority)


@dataclass(frozen=True)
class AppliedSetpoint:
    """One setpoint as sent: when (``sent_ns``), its stamp, the currents the drives got (A, from
    the raw setpoints sent) and the guard's note when it changed the request."""

    sent_ns: int
    stamp_ns: int
    currents: tuple[float, ...]
    seq: int
    profile_id: str
    last: bool
    reason: Optional[str]        # None: sent as requested; else why the guard changed it
    latched: bool                # the safe state was latched when it was prepared


@dataclass(frozen=True)
class _Queued:
    currents: tuple[float, ...]
    seq: int
    profile_id: str
    last: bool


@dataclass(frozen=True)
class _Prepared:
    queued: _Queued
    command: PreparedCommand


class SetpointPlayer:
    """Applies stamped current setpoints of one drive group at their stamps (see the module
    docstring). ``config`` None: the timing of ``master.config``."""

    def __init__(self, master: EposMaster, config: Optional[PlayerConfig] = None, *,
                 clock_ns: Callable[[], int] = time.time_ns, name: str = "ff-setpoint-player") -> None:
        self.master = master
        self.config = config if config is not None else PlayerConfig.from_bridge(master.config)
        self._clock_ns = clock_ns
        self._n_joints = len(master.joint_names)
        self._reports: deque[AppliedSetpoint] = deque(maxlen=MAX_REPORTS)
        self._scheduler = StampScheduler(self._apply, clock_ns=clock_ns,
                                         spin_margin=self.config.spin_margin,
                                         max_records=MAX_RECORDS,
                                         late_threshold=LATE_THRESHOLD, name=name,
                                         rt_priority=self.config.rt_priority,
                                         prepare=self._prepare if self.config.prepare_ahead else None)
        master.pending_fn = lambda: self._scheduler.pending > 0
        master.add_fault_listener(self._on_fault)

    # --- control ----------------------------------------------------------------------------
    def start(self) -> "SetpointPlayer":
        """Start the scheduler thread (idempotent)."""
        self._scheduler.start()
        return self

    def submit(self, stamp_ns: int, currents: Sequence[float], *, seq: int = 0,
               profile_id: str = "", last: bool = False) -> None:
        """Queue motor currents (A, one per joint) to be applied at ``stamp_ns`` (ns on
        ``clock_ns``); feeds the setpoint watchdog. SetpointRejected while the safe state is
        latched or for a wrong number of currents."""
        if self.master.latched:
            raise SetpointRejected(f"safe state ({self.master.fault_reason})")
        amps = tuple(float(c) for c in currents)
        if len(amps) != self._n_joints:
            raise SetpointRejected(f"{len(amps)} current(s) for {self._n_joints} joint(s) "
                                   f"{list(self.master.joint_names)}")
        # a motion runs (the watchdog watches) after a profile's setpoint that is not its last,
        # or after a manual setpoint with a non-zero current; a manual zero ends it
        running = not last and (bool(profile_id) or any(c != 0.0 for c in amps))
        self.master.note_setpoint(motion_running=running)
        self._scheduler.submit(int(stamp_ns), _Queued(amps, int(seq), str(profile_id), bool(last)))

    def clear(self) -> int:
        """Drop every pending setpoint; returns how many were dropped."""
        return self._scheduler.clear()

    def stop(self) -> None:
        """Drop pending setpoints, stop the thread, command zero current on every joint."""
        self._scheduler.stop()
        self.master.command_zero()

    def close(self) -> None:
        """``stop()`` and detach from the master (its safe state no longer reaches the player)."""
        self.stop()
        self.master.remove_fault_listener(self._on_fault)
        self.master.pending_fn = lambda: False

    def __enter__(self) -> "SetpointPlayer":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- what it reports --------------------------------------------------------------------
    @property
    def pending(self) -> int:
        """Setpoints queued and not yet applied."""
        return self._scheduler.pending

    def stats(self) -> SwitchStats:
        """Switch-time error sent − stamp (µs) over the applied setpoints, late and stale counts."""
        return self._scheduler.stats()

    def records(self) -> list[tuple[int, int]]:
        """(stamp ns, sent ns) of each applied setpoint, oldest first (up to ``MAX_RECORDS``)."""
        return list(self._scheduler.records)

    def reset_stats(self) -> None:
        """Forget the recorded switch times and the late / stale counts."""
        self._scheduler.reset_stats()

    def take_applied(self) -> list[AppliedSetpoint]:
        """The setpoints applied since the last call, oldest first."""
        out = []
        while self._reports:
            out.append(self._reports.popleft())
        return out

    def diagnostics(self) -> dict[str, float]:
        """Flat timing summary: switch count, late count, p50 / p99 / max of sent − stamp (µs),
        pending setpoints, and 1 when the thread runs under SCHED_FIFO (else 0)."""
        s = self.stats()
        return {"switch_count": s.count, "switch_late": s.late, "switch_p50_us": s.p50_us,
                "switch_p99_us": s.p99_us, "switch_max_us": s.max_us,
                "pending_setpoints": self.pending, "scheduler_realtime": int(self._scheduler.rt_active)}

    # --- the scheduler thread ---------------------------------------------------------------
    def _prepare(self, queued: _Queued) -> _Prepared:
        """Just before the stamp: safety guard + unit conversion."""
        return _Prepared(queued, self.master.prepare_currents(queued.currents))

    def _apply(self, stamp_ns: int, item: _Queued | _Prepared) -> None:
        """At the stamp: send the RPDOs, report what was sent."""
        prepared = item if isinstance(item, _Prepared) else self._prepare(item)
        master = self.master
        master.send_prepared(prepared.command)
        sent_ns = self._clock_ns()
        q, cmd = prepared.queued, prepared.command.command
        if q.last:
            master.guard.end_motion()
        currents = tuple(float(a) for a in master.applied_currents())
        self._reports.append(AppliedSetpoint(sent_ns, stamp_ns, currents, q.seq, q.profile_id,
                                             q.last, cmd.reason, cmd.latched))

    def _on_fault(self, reason: str) -> None:
        """Safe state latched (master's thread): nothing pending may be applied any more."""
        self._scheduler.clear()

"""Stamped current setpoints played onto the drives: setpoint → safety guard → units → RPDO of its
SYNC cycle (or at its stamp).

:class:`SetpointPlayer` is the one setpoint path, wherever it runs: in the bridge's process its
link to the drives is the :class:`~ff_hwbridge.drive.epos.EposMaster` itself; in the player
process (``drive.player_process``) it is that process's own bus connection
(:class:`~ff_hwbridge.drive.player_process.ChildLink`), which the same class drives. Either link
(:class:`DriveLink`) does the guard + units (``prepare_currents``), sends the RPDOs
(``send_prepared``), repeats the value in force in every SYNC cycle, and raises the reset epoch
at a safe state / fault reset. The player composes the three parts every stamped setpoint goes
through:

1. ``submit(stamp_ns, currents_A)`` feeds the setpoint watchdog (a motion runs after a profile's
   setpoint that is not its last, or after a manual setpoint with a non-zero current; a manual
   zero ends it) and queues the setpoint on a :class:`~ff_hwbridge.drive.scheduler.StampScheduler`.
2. Shortly before the stamp (``spin_margin`` s) the scheduler thread runs
   ``EposMaster.prepare_currents``: the :class:`~ff_hwbridge.drive.safety.SafetyGuard` (clamp to
   ±limit A, NaN/inf → 0 A, 0 A while latched) and the conversion to raw drive units.
3. At the stamp it sends the prepared RPDOs (``EposMaster.send_prepared``) and records
   sent − stamp for the switch-time statistics; the setpoint is reported as an
   :class:`AppliedSetpoint` (``take_applied()``).

Synchronous setpoints (``setpoint_timing: sync``, the default): the drives latch RPDOs at SYNC,
so a :class:`~ff_hwbridge.drive.cycle.CycleScheduler` replaces the stamp scheduler: each setpoint
is assigned to the first SYNC at or after its stamp, guarded, converted and sent as soon as the
SYNC before that one has been seen (up to one period early), and reported once its SYNC has come:
``AppliedSetpoint.sent_ns`` is then the SYNC's bus instant (when the drive applied it),
``rpdo_sent_ns`` the RPDO's bus instant (its echo's stamp; the send without an echo) and
``missed_cycles`` how many SYNCs late it took effect (counted; more than
``missed_cycle_tolerance`` latches the safe state).

Stops: a setpoint whose currents are all zero is a stop. Whatever the phase bookkeeping does, a
stop is never dropped (applied at once even when a later-stamped setpoint has been sent) and
the shift onto the grid never puts a setpoint before one stamped earlier that was submitted
before it (the shifted stamps keep the order of the stamps), so a zero stamped after a step
takes effect at or after it (:class:`~ff_hwbridge.drive.placement.GridPlacement`). A setpoint
that cannot be placed on the SYNC grid (due while no SYNC has been seen), or whose guard,
conversion or send fails, latches the safe state with the reason (``EposMaster.trip``), besides
the log.

A latched safe state drops every pending setpoint; ``stop()`` drops them, stops the thread and
commands zero current. Stamps are integer ns on ``clock_ns`` (default ``time.time_ns``, the ROS
system clock).
"""
from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, replace
from typing import Any, Callable, Optional, Protocol, Self, Sequence

import numpy as np

from ff_hwbridge.drive.config import BridgeConfig
from ff_hwbridge.drive.cycle import CycleScheduler, Resolved
from ff_hwbridge.drive.node import PreparedCommand
from ff_hwbridge.drive.safety import SafetyGuard
from ff_hwbridge.drive.placement import GridPlacement
from ff_hwbridge.drive.realtime import SWITCH_INTERVAL, RealtimeConfig, setup_process
from ff_hwbridge.drive.scheduler import StampScheduler, SwitchStats
from ff_hwbridge.drive.sync_watch import SyncWatch
from ff_hwbridge.protocol.units import DriveUnits

__all__ = ["SWITCH_INTERVAL", "AppliedSetpoint", "DriveLink", "PlayerConfig", "SetpointPlayer", "SetpointRejected"]


class DriveLink(Protocol):
    """What a player needs of the drives: ``EposMaster`` in the bridge's process, the player
    process's ``ChildLink`` in its own."""

    config: BridgeConfig
    guard: SafetyGuard
    sync_watch: SyncWatch
    echo: bool
    pending_fn: Callable[[], bool]

    @property
    def joint_names(self) -> tuple[str, ...]: ...
    @property
    def units(self) -> tuple[DriveUnits, ...]: ...
    @property
    def latched(self) -> bool: ...
    @property
    def fault_reason(self) -> Optional[str]: ...
    @property
    def reset_epoch_ns(self) -> int: ...
    def note_setpoint(self, motion_running: bool) -> None: ...
    def prepare_currents(self, amps: Sequence[float]) -> PreparedCommand: ...
    def send_prepared(self, prepared: PreparedCommand) -> tuple[int, ...]: ...
    def command_zero(self) -> None: ...
    def applied_currents(self) -> np.ndarray: ...
    def echo_time(self, marks: Sequence[int]) -> Optional[int]: ...
    def trip(self, reason: str) -> Optional[str]: ...
    def set_receiver_priority(self, priority: int) -> bool: ...
    def add_fault_listener(self, listener: Callable[[str], None]) -> None: ...
    def remove_fault_listener(self, listener: Callable[[str], None]) -> None: ...


def _sync_keeps_time(master: DriveLink) -> bool:
    """Whether the SYNC grid's clock may open a setpoint's window when the SYNC frame before it
    has not been seen here yet: when SYNC comes from a timer that keeps time while the frame's way
    to this process may not (another producer; the kernel's broadcast manager for this master's
    own SYNC on SocketCAN). Not for this master's own SYNC sent by a python-can thread (a late
    frame is late on the bus too) or seen only by the first drive's answer (no echo: the answer
    follows the SYNC): there a clock-opened window would let a setpoint out before that SYNC."""
    cfg = master.config
    return cfg.sync_producer != "master" or (cfg.bus.interface == "socketcan" and master.echo)


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

    cycle_tolerance: fraction of the SYNC period a stamp may lie after a SYNC and still be
                    assigned to it (float rounding, SYNC jitter).
    stall_dump:     s: the synchronous player's thread away this long while setpoints are pending
                    dumps every thread's stack to stderr (``StallDump``); 0 = off.
    """

    spin_margin: float = 0.0003
    rt_priority: int = 0
    prepare_ahead: bool = True
    cycle_tolerance: float = 0.1
    stall_dump: float = 0.0

    @classmethod
    def from_bridge(cls, config: BridgeConfig) -> "PlayerConfig":
        """The timing of a bridge configuration (``spin_margin``, ``scheduler_rt_priority``,
        ``stall_dump``)."""
        return cls(spin_margin=config.spin_margin, rt_priority=config.rt_priority,
                   stall_dump=float(config.stall_dump))


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
    rpdo_sent_ns: int = 0        # its RPDO's bus instant (sync: before ``sent_ns``, the SYNC)
    missed_cycles: int = 0       # sync: SYNC cycles after its own that it took effect (0 = on time)


@dataclass(frozen=True)
class _Queued:
    currents: tuple[float, ...]
    seq: int
    profile_id: str
    last: bool
    stamp_ns: int = 0         # as submitted (before any shift onto the SYNC grid)


@dataclass(frozen=True)
class _Prepared:
    queued: _Queued
    command: PreparedCommand


class PlayerBase:
    """What :class:`SetpointPlayer` and the process player share: joining and leaving the
    master (its pending check, its safe-state listener), the context manager, handing over the
    applied setpoints and the switch part of the diagnostics."""

    master: DriveLink
    _reports: deque[AppliedSetpoint]
    _n_joints: int

    def start(self) -> Self:
        raise NotImplementedError

    def stop(self) -> None:
        raise NotImplementedError

    def stats(self) -> SwitchStats:
        raise NotImplementedError

    @property
    def pending(self) -> int:
        raise NotImplementedError

    def _on_fault(self, reason: str) -> None:
        raise NotImplementedError

    def _accept(self, currents: Sequence[float], profile_id: str, last: bool,
                refusal: Optional[str] = None, *, stamp_ns: int = 0) -> tuple[float, ...]:
        """A submitted setpoint's currents (A) as floats, once checked, and the setpoint watchdog
        fed. SetpointRejected while the safe state is latched, with ``refusal`` (why this player
        takes none now), for a stamp (ns) before the latest safe state / fault reset (the current
        stays 0 until a setpoint stamped after it) or for a wrong number of currents."""
        if self.master.latched:
            raise SetpointRejected(f"safe state ({self.master.fault_reason})")
        if refusal is not None:
            raise SetpointRejected(refusal)
        epoch = self.master.reset_epoch_ns
        if int(stamp_ns) < epoch:
            raise SetpointRejected(f"stamped {(epoch - int(stamp_ns)) / 1e6:.1f} ms before the latest "
                                   "safe state / fault reset: the current stays 0 until a setpoint "
                                   "stamped after it")
        amps = tuple(float(c) for c in currents)
        if len(amps) != self._n_joints:
            raise SetpointRejected(f"{len(amps)} current(s) for {self._n_joints} joint(s) "
                                   f"{list(self.master.joint_names)}")
        # a motion runs (the watchdog watches) after a profile's setpoint that is not its last,
        # or after a manual setpoint with a non-zero current; a manual zero ends it
        running = not last and (bool(profile_id) or any(c != 0.0 for c in amps))
        self.master.note_setpoint(motion_running=running)
        return amps

    def _attach(self) -> None:
        """The master's pending check asks this player; its safe state reaches ``_on_fault``."""
        self.master.pending_fn = lambda: self.pending > 0
        self.master.add_fault_listener(self._on_fault)

    def _release(self) -> None:
        """What ``close()`` frees between stopping and detaching (nothing here)."""

    def close(self) -> None:
        """``stop()`` and detach from the master (its safe state no longer reaches the player)."""
        self.stop()
        self._release()
        self.master.remove_fault_listener(self._on_fault)
        self.master.pending_fn = lambda: False

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def take_applied(self) -> list[AppliedSetpoint]:
        """The setpoints applied since the last call, oldest first."""
        out = []
        while self._reports:
            out.append(self._reports.popleft())
        return out

    def _switch_diagnostics(self) -> dict[str, float]:
        """Switch count, late count, p50 / p99 / max of the switch error (µs), pending setpoints."""
        s = self.stats()
        return {"switch_count": s.count, "switch_late": s.late, "switch_p50_us": s.p50_us,
                "switch_p99_us": s.p99_us, "switch_max_us": s.max_us, "pending_setpoints": self.pending}


class SetpointPlayer(PlayerBase):
    """Applies stamped current setpoints of one drive group at their stamps (see the module
    docstring). ``config`` None: the timing of ``master.config``."""

    def __init__(self, master: DriveLink, config: Optional[PlayerConfig] = None, *,
                 clock_ns: Callable[[], int] = time.time_ns, name: str = "ff-setpoint-player") -> None:
        self.master = master
        self.config = config if config is not None else PlayerConfig.from_bridge(master.config)
        self._clock_ns = clock_ns
        self._n_joints = len(master.joint_names)
        self._reports: deque[AppliedSetpoint] = deque(maxlen=MAX_REPORTS)
        #: called with each applied setpoint as it is reported (the player process's pipe)
        self.on_applied: Optional[Callable[[AppliedSetpoint], None]] = None
        self.synchronous = master.config.synchronous
        self._cycle: Optional[CycleScheduler] = None
        if self.synchronous:
            self._cycle = CycleScheduler(
                master.sync_watch, self._send_cycle, self._report_cycle, echo_time=master.echo_time,
                prepare=self._prepare, on_fault=master.trip,
                tolerance=self.config.cycle_tolerance,
                missed_tolerance=master.config.missed_cycle_tolerance,
                rt_priority=self.config.rt_priority, max_records=MAX_RECORDS, name=name,
                clock_ns=clock_ns, clock_opens=_sync_keeps_time(master),
                stall_dump=self.config.stall_dump)
        self._scheduler: StampScheduler | CycleScheduler = self._cycle or StampScheduler(self._apply, clock_ns=clock_ns,
                                         spin_margin=self.config.spin_margin,
                                         max_records=MAX_RECORDS,
                                         late_threshold=LATE_THRESHOLD, name=name,
                                         rt_priority=self.config.rt_priority,
                                         prepare=self._prepare if self.config.prepare_ahead else None,
                                         on_error=master.trip)
        # synchronous: one shift onto the SYNC grid per profile run, the order of stamps kept
        self._placement = GridPlacement(self._cycle.grid) if self._cycle is not None else None
        self._attach()

    # --- control ----------------------------------------------------------------------------
    def start(self) -> Self:
        """Start the scheduler thread (idempotent). Synchronous: the process's thread switch
        interval at most ``SWITCH_INTERVAL`` (the bus receiver and this thread get the GIL back
        from busy threads that fast) and the bus receiver under the thread's SCHED_FIFO."""
        if self._cycle is not None:
            setup_process(RealtimeConfig(switch_interval=SWITCH_INTERVAL), "setpoint player")
            if self.config.rt_priority > 0:
                self.master.set_receiver_priority(self.config.rt_priority)
        self._scheduler.start()
        return self

    def submit(self, stamp_ns: int, currents: Sequence[float], *, seq: int = 0,
               profile_id: str = "", last: bool = False) -> None:
        """Queue motor currents (A, one per joint) to be applied at ``stamp_ns`` (ns on
        ``clock_ns``); feeds the setpoint watchdog. SetpointRejected while the safe state is
        latched or for a wrong number of currents."""
        amps = self._accept(currents, profile_id, last, stamp_ns=stamp_ns)
        stamp = int(stamp_ns)
        stop = all(c == 0.0 for c in amps)
        if self._placement is not None:
            stamp = self._placement.place(stamp, str(profile_id), int(seq))
        self._scheduler.submit(stamp, _Queued(amps, int(seq), str(profile_id), bool(last), int(stamp_ns)), stop=stop)

    def clear(self) -> int:
        """Drop every pending setpoint; returns how many were dropped."""
        return self._scheduler.clear()

    def stop(self) -> None:
        """Drop pending setpoints, stop the thread, command zero current on every joint."""
        self._scheduler.stop()
        self.master.command_zero()

    def _release(self) -> None:
        """The SYNC cycle stops listening to the SYNC watch."""
        if self._cycle is not None:
            self._cycle.close()

    # --- what it reports --------------------------------------------------------------------
    @property
    def pending(self) -> int:
        """Setpoints queued and not yet applied."""
        return self._scheduler.pending

    def stats(self) -> SwitchStats:
        """Switch-time error sent − stamp (µs) over the applied setpoints, late and stale counts."""
        return self._scheduler.stats()

    def records(self) -> list[tuple[int, int]]:
        """(stamp ns, sent ns) of each applied setpoint, oldest first (up to ``MAX_RECORDS``);
        synchronous: (stamp ns, bus instant of the SYNC it took effect at)."""
        return list(self._scheduler.records)

    def reset_stats(self) -> None:
        """Forget the recorded switch times and the late / stale / missed counts."""
        self._scheduler.reset_stats()
        if self._cycle is not None:
            self.master.sync_watch.reset_stats()

    def sync_grid(self) -> Optional[tuple[int, int]]:
        """(bus instant ns of the latest SYNC, SYNC period ns), on the stamps' clock, for
        aligning a profile's start to the SYNC grid; None when not synchronous or before SYNC."""
        return self._cycle.grid() if self._cycle is not None else None

    def diagnostics(self) -> dict[str, float]:
        """Flat timing summary: switch count, late count, p50 / p99 / max of sent − stamp (µs;
        synchronous: SYNC instant − stamp), pending setpoints, 1 when the thread runs under
        SCHED_FIFO (else 0); synchronous also: missed setpoints and the worst miss (cycles),
        SYNC count, period, jitter p99 / max, missing SYNCs (µs / counts), send after SYNC p99."""
        out = self._switch_diagnostics()
        out.update({"scheduler_realtime": int(self._scheduler.rt_active),
                    "synchronous": int(self.synchronous)})
        if self._cycle is not None:
            c = self._cycle.cycle_stats()
            w = self.master.sync_watch.stats()
            out.update({"missed_setpoints": c.missed, "missed_cycles_max": c.missed_max_cycles,
                        "superseded_setpoints": c.superseded, "late_stops": self._cycle.late_stops,
                        "send_after_sync_p99_us": c.send_after_sync_p99_us,
                        "sync_count": w.count, "sync_period_us": w.period_us,
                        "sync_jitter_p99_us": w.jitter_p99_us, "sync_jitter_max_us": w.jitter_max_us,
                        "sync_missing": w.missing, "sync_age_ms": w.age_ms,
                        "stale_setpoints": self._cycle.stale, "stale_stops": self._cycle.stale_stops,
                        "player_errors": self._cycle.errors})
        return out

    # --- the scheduler thread ---------------------------------------------------------------
    def _prepare(self, queued: _Queued) -> _Prepared:
        """Just before the stamp: safety guard + unit conversion; 0 A for a setpoint queued
        before the latest safe state / fault reset."""
        if queued.stamp_ns < self.master.reset_epoch_ns:
            queued = replace(queued, currents=(0.0,) * len(queued.currents))
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
        self._tell(AppliedSetpoint(sent_ns, stamp_ns, currents, q.seq, q.profile_id, q.last, cmd.reason,
                                   cmd.latched))

    def _send_cycle(self, stamp_ns: int, prepared: _Prepared) -> tuple[Optional[tuple[int, ...]], Any]:
        """During the cycle before its SYNC: send the RPDOs (the drives latch them at it)."""
        master = self.master
        marks = master.send_prepared(prepared.command)
        if prepared.queued.last:
            master.guard.end_motion()
        token = (prepared, tuple(float(a) for a in master.applied_currents()))
        return (marks if master.echo else None), token

    def _report_cycle(self, r: Resolved) -> None:
        """Its SYNC has come: report it applied at the SYNC's bus instant."""
        prepared, currents = r.token
        q, cmd = prepared.queued, prepared.command.command
        self._tell(AppliedSetpoint(r.applied_ns, r.stamp_ns, currents, q.seq, q.profile_id, q.last,
                                   cmd.reason, cmd.latched, r.sent_ns, r.missed_cycles))

    def _tell(self, applied: AppliedSetpoint) -> None:
        self._reports.append(applied)
        if self.on_applied is not None:
            self.on_applied(applied)

    def _on_fault(self, reason: str) -> None:
        """Safe state latched (master's thread): nothing pending may be applied any more."""
        self._scheduler.clear()

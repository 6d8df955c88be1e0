"""The synchronous setpoint player in a process of its own (``player_process: true``).

The bridge's process runs the ROS executor, whose threads hold the GIL for ms at a time; a player
thread there waits for the GIL before each send. :class:`ProcessPlayer` has the interface of
:class:`~ff_hwbridge.drive.player.SetpointPlayer` and runs THE SAME player class in a child
process (``multiprocessing``, spawn) that imports no ROS and runs no executor; the child is a
thin wrapper:

- :class:`ChildLink` is the player's link to the drives there: its own python-can connection
  (``receive_own_messages`` where the interface has it; socketcan allows several sockets, the
  simulation's hub several clients), its own :class:`~ff_hwbridge.drive.sync_watch.SyncWatch`
  fed by its receiver thread, guard + units (``prepare_currents``: ±limit A, NaN → 0 A, raw
  0x6071 ‰ / 0x2030 mA) and the master's own RPDO writer, :class:`~ff_hwbridge.drive.rpdo.
  SetpointRpdos` (RPDO1 per joint, controlword + setpoint clamped to the limit; every SYNC it
  sees, each drive the gate lets it drive gets its RPDO1 once, the value in force repeated when
  no new setpoint went out in that cycle: the drive's interpolation-period supervision, 0x60C2 /
  EMCY 0x8250, is what stops a drive whose player froze), with this placement's parameters:
  ownership from the gate, its own echoes told from the master's frames by their content;
- what it may send comes from the master through shared memory (:meth:`EposMaster.gate`: per
  joint the controlword and whether a current may be sent; the master updates it before it
  sends a new controlword or its safe-state reaction), so the child never re-enables a drive
  the master stops and sends 0 A while the safe state is latched;
- a safe state or fault reset raises the reset epoch (wall ns, shared memory): the child forgets
  the value in force (0 until a new setpoint), drops what is queued and refuses setpoints
  stamped before it, as the player does in the bridge's process;
- the bridge's process only feeds it (``submit`` → a pipe) and reports: applied setpoints,
  faults and the statistics come back over the pipe. A fault the child reports (a miss beyond
  ``missed_cycle_tolerance``, a setpoint that cannot be placed, a failing send) latches the
  master's safe state with its reason; a child that dies or stops reporting for ``DEAD_AFTER``
  s latches it too (the drive stops by itself a cycle or two after the last RPDO: EMCY 0x8250).

The master keeps the state machine, the watchdogs and the reactions; while the player owns an
enabled drive it sends RPDO1 with 0 current only and no refresh of its own
(``EposMaster.external_player``).
"""
from __future__ import annotations

import dataclasses
import logging
import multiprocessing as mp
import threading
import time
from collections import deque
from typing import Any, Callable, Optional, Self, Sequence

import can
import numpy as np

from ff_hwbridge.drive.bus import open_bus
from ff_hwbridge.drive.config import BridgeConfig
from ff_hwbridge.drive.epos import EposMaster
from ff_hwbridge.drive.node import ECHO_INTERFACES, SYNC_COB_ID, PreparedCommand
from ff_hwbridge.drive.player import (MAX_REPORTS, AppliedSetpoint, PlayerBase, PlayerConfig, SetpointPlayer,
                                      SetpointRejected)
from ff_hwbridge.drive.realtime import SWITCH_INTERVAL, IdleCollector, RealtimeConfig, setup_process, use_fifo
from ff_hwbridge.drive.rpdo import EchoMatch, RpdoChannel, SetpointRpdos
from ff_hwbridge.drive.safety import SafetyGuard
from ff_hwbridge.drive.scheduler import SwitchStats
from ff_hwbridge.drive.sync_watch import SyncWatch
from ff_hwbridge.protocol.epos_od import rpdo_layout, struct_format
from ff_hwbridge.protocol.units import DriveUnits

log = logging.getLogger(__name__)

__all__ = ["ChildLink", "ProcessPlayer"]

STATUS_PERIOD = 0.02      # s, the child's status report (pending, heartbeat)
STATS_PERIOD = 0.25       # s, ... with statistics refreshed this often
DEAD_AFTER = 2.0          # s without a status report: the player process counts as dead
START_TIMEOUT = 30.0      # s for the child to import, open the bus and report ready


# --- the child ------------------------------------------------------------------------------------
class ChildLink:
    """The player's link to the drives in the player process (see the module docstring): a
    :class:`~ff_hwbridge.drive.player.DriveLink`. ``gate``: shared ints [cw_0, ok_0, cw_1, ok_1,
    ..., latched]; ``epoch``: shared 64-bit value, the master's reset epoch (wall ns);
    ``tell(*msg)``: to the bridge's process."""

    def __init__(self, config: BridgeConfig, gate: Any, epoch: Any, tell: Callable[..., None]) -> None:
        self.config = config
        self.gate, self._epoch, self.tell = gate, epoch, tell
        self.n = len(config.joints)
        cfg = config.bus.as_dict()
        self.echo = cfg.get("interface") in ECHO_INTERFACES
        if self.echo:
            cfg["receive_own_messages"] = True
        # only SYNC and the setpoint RPDOs (our echoes) are of interest here; given at open, the
        # simulation's hub applies them on its side too and sends this process nothing else
        ids = [SYNC_COB_ID] + [0x200 + j.node_id for j in config.joints]
        filters = [can.typechecking.CanFilter(can_id=i, can_mask=0x7FF) for i in ids]
        cfg["can_filters"] = filters
        self.bus = open_bus(cfg)
        try:
            self.bus.set_filters(filters)
        except (NotImplementedError, can.CanError, AttributeError):
            pass
        self.sync_watch = SyncWatch(config.sync_period)
        self.guard = SafetyGuard(config.current_limits, config.setpoint_timeout)
        self.pending_fn: Callable[[], bool] = lambda: False
        self._units = [j.units for j in config.joints]
        self._limits = [float(j.current_limit) for j in config.joints]
        # the setpoint RPDOs (``drive.rpdo``): this link owns a drive's while the gate lets it
        # send a current (with the gate's controlword); the master's frames of the COB-ID reach
        # this connection too, so its own echoes are told by their content
        self.rpdos = SetpointRpdos(
            [RpdoChannel(0x200 + j.node_id, struct_format(rpdo_layout(j.units.family)),
                         j.units.setpoint_limit(j.current_limit)) for j in config.joints],
            self._transmit, lambda: self.sync_watch.count, owner=self._owner, zero_current=lambda: self.latched,
            echo=EchoMatch.SENT_FRAMES, forget_when_not_owned=True)
        self._lock = self.rpdos.lock
        self.received = 0
        self.epoch = 0                            # the reset epoch last acted on
        self._listeners: list[Callable[[str], None]] = []
        self._rx_thread: Optional[threading.Thread] = None
        self.rx_rt = False
        self.stopped = threading.Event()
        self.sync_watch.add_listener(self._on_cycle)

    # --- DriveLink ----------------------------------------------------------------------------
    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.config.joint_names

    @property
    def units(self) -> tuple[DriveUnits, ...]:
        return tuple(self._units)

    @property
    def latched(self) -> bool:
        return bool(self.gate[2 * self.n])

    @property
    def raw(self) -> list[int]:
        """The value in force (raw setpoint), per joint."""
        return [ch.setpoint for ch in self.rpdos.channels]

    @property
    def repeats(self) -> int:
        return self.rpdos.repeats

    @property
    def fault_reason(self) -> Optional[str]:
        return "safe state latched by the bridge" if self.latched else None

    @property
    def reset_epoch_ns(self) -> int:
        return int(self._epoch.value) if self._epoch is not None else 0

    def note_setpoint(self, motion_running: bool) -> None:
        """The bridge's master runs the setpoint watchdog (fed where ``submit`` is called)."""

    def add_fault_listener(self, listener: Callable[[str], None]) -> None:
        self._listeners.append(listener)

    def remove_fault_listener(self, listener: Callable[[str], None]) -> None:
        if listener in self._listeners:
            self._listeners.remove(listener)

    def trip(self, reason: str) -> Optional[str]:
        """A fault of the player here: the bridge's master latches the safe state with it."""
        self.tell("fault", reason)
        return reason

    def set_receiver_priority(self, priority: int) -> bool:
        t = self._rx_thread
        if t is None or not t.is_alive():
            return False
        self.rx_rt = use_fifo(priority, "player process bus receiver", tid=t.native_id or 0)
        return self.rx_rt

    def prepare_currents(self, amps: Sequence[float]) -> PreparedCommand:
        """Guard (±limit A, NaN → 0 A; 0 A while the bridge's safe state is latched) + units."""
        cmd = self.guard.filter(amps)
        if self.latched:
            return PreparedCommand(cmd, (0,) * self.n)
        return PreparedCommand(cmd, tuple(u.amps_to_setpoint(float(a), limit=lim)
                                          for u, a, lim in zip(self._units, cmd.currents, self._limits)))

    def send_prepared(self, prepared: PreparedCommand) -> tuple[int, ...]:
        """One RPDO per joint the gate lets this player drive (0 for the others: the master owns
        their RPDO); per joint the RPDO count including it (0: none sent)."""
        self.check_epoch()
        marks = []
        for i, raw in enumerate(prepared.raw):
            with self._lock:            # a cycle's repeat never goes between a send and its record
                cw = self._owner(i)
                if cw is None:
                    self.rpdos.channels[i].setpoint = 0
                    marks.append(0)
                    continue
                marks.append(self.rpdos.send(i, cw, int(raw)))
        return tuple(marks)

    def command_zero(self) -> None:
        """The value in force 0 on every joint (sent where the gate lets this player drive)."""
        self.send_prepared(PreparedCommand(self.guard.filter([0.0] * self.n), (0,) * self.n))

    def applied_currents(self) -> np.ndarray:
        return np.array([u.setpoint_to_amps(r) for u, r in zip(self._units, self.raw)])

    def echo_time(self, marks: Sequence[int]) -> Optional[int]:
        return self.rpdos.echo_time(marks)

    # --- the RPDOs ----------------------------------------------------------------------------
    def _owner(self, i: int) -> Optional[int]:
        """The gate's controlword while it lets this player send joint ``i`` a current, else
        None (the master owns that RPDO)."""
        if bool(self.gate[2 * i + 1]) and not self.gate[2 * self.n]:
            return int(self.gate[2 * i])
        return None

    def _transmit(self, cob_id: int, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=cob_id, data=data, is_extended_id=False))

    def check_epoch(self) -> None:
        """A new reset epoch (a safe state / fault reset in the master): the value in force is
        0 from now on, and the player drops what it has queued (its fault listener)."""
        e = self.reset_epoch_ns
        if e == self.epoch:
            return
        with self._lock:
            if e == self.epoch:
                return
            self.epoch = e
            self.rpdos.forget()
        for fn in list(self._listeners):
            fn("reset epoch")

    def _on_cycle(self, ev: Any) -> None:
        """A SYNC seen (receiver thread): each enabled drive's RPDO1 once in the cycle it opens."""
        self.check_epoch()
        self.rpdos.on_cycle(ev)

    def start_receiver(self) -> None:
        """Start the receiver thread (``receive``)."""
        self._rx_thread = threading.Thread(target=self.receive, name="ff-player-rx", daemon=True)
        self._rx_thread.start()

    def receive(self) -> None:
        """The receiver thread: SYNC into the watch, our own RPDOs' echoes (their bus instants)."""
        failures = 0
        while not self.stopped.is_set():
            try:
                msg = self.bus.recv(0.1)
                failures = 0
            except Exception as exc:  # noqa: BLE001
                if self.stopped.is_set():
                    return
                failures += 1
                if failures == 1:
                    log.exception("player process: bus receive failed")
                if failures >= 20:            # the bus is gone: tell the bridge, stop
                    self.tell("fault", f"setpoint player process: the bus is gone ({type(exc).__name__}: {exc})")
                    self.stopped.set()
                    return
                time.sleep(0.01)
                continue
            if msg is None:
                continue
            cid = msg.arbitration_id
            if cid == SYNC_COB_ID:
                self.sync_watch.observe(msg.timestamp, self.rpdos.echoes() if self.echo else None)
            elif (i := self.rpdos.index(cid)) is not None:
                ts = int(round(msg.timestamp * 1e9)) if msg.timestamp else time.time_ns()
                self.rpdos.on_echo(i, bytes(msg.data), ts)

    def close(self) -> None:
        self.stopped.set()
        try:
            self.bus.shutdown()
        except (OSError, can.CanError) as exc:
            # the receiver thread may be reading the connection as it closes, or the bus went
            # first (the hub stopped): nothing is left to send on it
            log.debug("closing the player's bus: %s", exc)


def _child_main(config: BridgeConfig, player_config: PlayerConfig, conn: Any, gate: Any, epoch: Any) -> None:
    """The player process: one :class:`SetpointPlayer` on a :class:`ChildLink`, fed from the pipe."""
    logging.basicConfig(level=logging.WARNING, format="%(name)s: %(message)s")
    conn_lock = threading.Lock()

    def tell(*msg: Any) -> None:
        with conn_lock:
            try:
                conn.send(msg)
            except (OSError, EOFError, BrokenPipeError):
                link.stopped.set()

    try:
        link = ChildLink(config, gate, epoch, tell)
    except Exception as exc:  # noqa: BLE001 - told to the parent, which latches the safe state
        conn.send(("fault", f"setpoint player process could not start: {type(exc).__name__}: {exc}"))
        return
    player = SetpointPlayer(link, player_config, name="ff-player-process")
    player.on_applied = lambda a: tell("applied", a)
    # the heap built so far frozen (later full collections only while nothing is pending), and
    # no thread here holding the GIL at normal priority
    setup_process(RealtimeConfig(priority=max(0, player_config.rt_priority - 1), switch_interval=SWITCH_INTERVAL,
                                 freeze_gc=True), "setpoint player process")
    link.start_receiver()           # before the player's start: it raises the receiver's priority
    threading.Thread(target=_status, args=(link, player, tell), name="ff-player-status", daemon=True).start()
    player.start()
    tell("ready")
    try:
        while not link.stopped.is_set():
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                break
            kind = msg[0]
            if kind == "sp":
                _, stamp, amps, seq, pid, last = msg
                link.received += 1
                link.check_epoch()
                try:
                    player.submit(stamp, amps, seq=seq, profile_id=pid, last=last)
                except SetpointRejected:
                    continue              # from before the latest safe state / reset
            elif kind == "clear":
                player.clear()
            elif kind == "reset_stats":
                player.reset_stats()
            elif kind == "stop":
                break
    finally:
        link.stopped.set()
        player.close()
        link.close()


def _status(link: ChildLink, player: SetpointPlayer, tell: Callable[..., None]) -> None:
    """The child's status to the bridge every ``STATUS_PERIOD`` s (its heartbeat there)."""
    if player.config.rt_priority > 0:
        use_fifo(player.config.rt_priority, "player process status")
    idle_gc = IdleCollector(lambda: player.pending == 0)
    figures_at, was_pending = 0.0, False
    diag: dict[str, float] = {}
    stats = player.stats()
    while not link.stopped.wait(STATUS_PERIOD):
        idle_gc.tick()
        link.check_epoch()
        now = time.monotonic()
        pending = player.pending
        # percentiles: numpy, but not for free; fresh at once when a stream has ended
        if now - figures_at >= STATS_PERIOD or (was_pending and not pending):
            figures_at = now
            stats, diag = player.stats(), player.diagnostics()
            diag["scheduler_realtime"] = int(diag.get("scheduler_realtime", 0)
                                             and (link.rx_rt or player.config.rt_priority <= 0))
            diag["cycle_repeats"] = link.repeats
        was_pending = pending > 0
        tell("status", link.received, pending, stats, diag, player.sync_grid())


# --- the bridge's side --------------------------------------------------------------------------
class ProcessPlayer(PlayerBase):
    """:class:`SetpointPlayer`'s interface, played by a child process (module docstring)."""

    synchronous = True
    master: EposMaster

    def __init__(self, master: EposMaster, config: Optional[PlayerConfig] = None, *,
                 clock_ns: Callable[[], int] = time.time_ns, start_timeout: float = START_TIMEOUT) -> None:
        if not master.config.synchronous:
            raise ValueError("a player process needs setpoint_timing: sync")
        self.master = master
        self.config = config if config is not None else PlayerConfig.from_bridge(master.config)
        self._clock_ns = clock_ns
        self._start_timeout = start_timeout
        self._n = self._n_joints = len(master.joint_names)
        ctx = mp.get_context("spawn")
        self._ctx = ctx
        self._gate = ctx.Array("i", 2 * self._n + 1, lock=False)
        self._epoch = ctx.Value("q", 0, lock=False)      # the master's reset epoch, wall ns
        self._proc: Optional[Any] = None
        self._conn: Optional[Any] = None
        self._conn_lock = threading.Lock()
        self._reader: Optional[threading.Thread] = None
        self._closing = False
        self._reports: deque[AppliedSetpoint] = deque(maxlen=MAX_REPORTS)
        self.records_: deque[tuple[int, int]] = deque(maxlen=200_000)
        self._submitted = 0
        self._status: Optional[tuple] = None
        self._status_at = time.monotonic()
        self._ready = threading.Event()
        self.exit_reason: Optional[str] = None
        self._attach()

    def _resolved_config(self) -> BridgeConfig:
        """The master's config with each joint's units as the master resolved them at configure:
        the drive's own motor data where it takes them from the drive (``scaling_source: drive``,
        ``read_motor_data``), so the child converts A to the drive's raw setpoint (and clamps it
        to the limit) on the same base as the master does."""
        cfg = self.master.config
        joints = tuple(dataclasses.replace(j, units=u) for j, u in zip(cfg.joints, self.master.units))
        return dataclasses.replace(cfg, joints=joints)

    # --- control ------------------------------------------------------------------------------
    def start(self) -> Self:
        """Spawn the player process and wait until it has opened the bus (idempotent)."""
        if self._proc is not None and self._proc.is_alive():
            return self
        if self.config.rt_priority > 0:       # the master's watchdogs see the TPDOs in time
            self.master.set_receiver_priority(self.config.rt_priority)
        self._write_gate()
        parent, child = self._ctx.Pipe()
        self._conn = parent
        self._ready.clear()
        self._proc = self._ctx.Process(target=_child_main,
                                       args=(self._resolved_config(), self.config, child, self._gate, self._epoch),
                                       name="ff-setpoint-player", daemon=True)
        self._proc.start()
        child.close()
        # its start-up (interpreter, imports, bus) at normal priority: under SCHED_FIFO it would
        # hold a CPU for a few hundred ms, and a normal-priority thread of this process holding
        # the GIL, preempted meanwhile, would hold off the bus receiver that writes every SYNC
        # cycle's RPDO until the child is ready (the drive faults 0x8250 after one empty cycle);
        # the child takes SCHED_FIFO itself once it runs
        self.master.gate_listener = self._write_gate
        self._status_at = time.monotonic() + self._start_timeout
        self._reader = threading.Thread(target=self._read, name="ff-player-reader", daemon=True)
        self._reader.start()
        if not self._ready.wait(self._start_timeout):
            self._died("the setpoint player process did not start within "
                       f"{self._start_timeout:g} s")
        else:
            self._write_gate()
            self.master.external_player = True    # from now on the child refreshes the RPDOs
        return self

    def _write_gate(self) -> None:
        self._epoch.value = int(self.master.reset_epoch_ns)    # first: the child forgets first
        g = self.master.gate()
        for i, (cw, ok) in enumerate(g):
            self._gate[2 * i] = int(cw)
            self._gate[2 * i + 1] = int(ok)
        self._gate[2 * self._n] = int(self.master.latched)

    def _tell(self, *msg: Any) -> None:
        conn = self._conn
        if conn is None:
            return
        with self._conn_lock:
            try:
                conn.send(msg)
            except (OSError, EOFError, BrokenPipeError, ValueError):
                pass

    def submit(self, stamp_ns: int, currents: Sequence[float], *, seq: int = 0,
               profile_id: str = "", last: bool = False) -> None:
        """As :meth:`SetpointPlayer.submit`; the setpoint goes to the player process."""
        amps = self._accept(currents, profile_id, last, self.exit_reason, stamp_ns=stamp_ns)
        self._submitted += 1
        self._tell("sp", int(stamp_ns), amps, int(seq), str(profile_id), bool(last))

    def clear(self) -> int:
        """Drop every pending setpoint (in the player process); returns how many were pending."""
        n = self.pending
        self._tell("clear")
        return n

    def stop(self) -> None:
        """Stop the player process, hand the RPDOs back to the master, command zero current."""
        self._closing = True
        self.master.external_player = False      # the master's refresh again
        self._tell("stop")
        proc = self._proc
        if proc is not None:
            proc.join(3.0)
            if proc.is_alive():
                proc.terminate()
                proc.join(2.0)
        self.master.external_player = False
        self.master.gate_listener = None
        if self._conn is not None:
            self._conn.close()
            self._conn = None
        self._proc = None
        self.master.command_zero()

    @property
    def pid(self) -> Optional[int]:
        return self._proc.pid if self._proc is not None else None

    # --- what comes back ----------------------------------------------------------------------
    def _read(self) -> None:
        conn = self._conn
        assert conn is not None
        if self.config.rt_priority > 0:       # faults reach the master without delay
            use_fifo(self.config.rt_priority, "player process reader")
        while True:
            try:
                if not conn.poll(0.1):
                    if not self._closing and time.monotonic() - self._status_at > DEAD_AFTER:
                        alive = self._proc is not None and self._proc.is_alive()
                        self._died("the setpoint player process "
                                   + ("stopped reporting" if alive else
                                      f"died (exit code {self._proc.exitcode if self._proc else None})"))
                        return
                    continue
                msg = conn.recv()
            except (EOFError, OSError, ValueError):
                if not self._closing:
                    code = self._proc.exitcode if self._proc is not None else None
                    self._died(f"the setpoint player process died (exit code {code})")
                return
            kind = msg[0]
            if kind == "applied":
                a: AppliedSetpoint = msg[1]
                self._reports.append(a)
                self.records_.append((a.stamp_ns, a.sent_ns))
                if a.last:
                    self.master.guard.end_motion()
            elif kind == "status":
                self._status = msg
                self._status_at = time.monotonic()
            elif kind == "ready":
                self._ready.set()
                self._status_at = time.monotonic()
            elif kind == "fault":
                self.master.trip(str(msg[1]))

    def _died(self, reason: str) -> None:
        self.exit_reason = reason
        log.error("%s", reason)
        self.master.external_player = False     # the master's own RPDOs carry the reaction
        self.master.trip(reason)

    def _on_fault(self, reason: str) -> None:
        self._write_gate()
        self._tell("clear")

    @property
    def pending(self) -> int:
        """Setpoints submitted and not yet applied (0 once the player process is gone)."""
        st = self._status
        if self.exit_reason is not None:
            return 0
        if st is None:
            return self._submitted
        return max(0, self._submitted - int(st[1])) + int(st[2])

    def stats(self) -> SwitchStats:
        st = self._status
        if st is None:
            nan = float("nan")
            return SwitchStats(0, 0, 0, nan, nan, nan, nan)
        return st[3]

    def records(self) -> list[tuple[int, int]]:
        return list(self.records_)

    def reset_stats(self) -> None:
        self.records_.clear()
        self._tell("reset_stats")
        self._status = None if self._status is None else self._status[:3] + (
            SwitchStats(0, 0, 0, *(float("nan"),) * 4),) + self._status[4:]

    def sync_grid(self) -> Optional[tuple[int, int]]:
        st = self._status
        return None if st is None else st[5]

    def diagnostics(self) -> dict[str, float]:
        """As :meth:`SetpointPlayer.diagnostics` (the child's), plus ``player_process`` 1, its
        pid, and the pending setpoints and switch statistics seen from here."""
        out: dict[str, float] = {"scheduler_realtime": 0, "synchronous": 1}
        st = self._status
        if st is not None:
            out.update(st[4])
        out.update(self._switch_diagnostics())
        out.update({"player_process": 1, "player_pid": float(self.pid or 0)})
        return out

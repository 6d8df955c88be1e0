"""The synchronous setpoint player in a process of its own (``player_process: true``).

The bridge's process runs the ROS executor, whose threads hold the GIL for ms at a time; a player
thread there, SCHED_FIFO or not, waits for the GIL before each send. :class:`ProcessPlayer` has
the same interface as :class:`~ff_hwbridge.drive.player.SetpointPlayer` but plays in a child
process (``multiprocessing``, spawn) that imports no ROS and runs no executor:

- the child opens its own python-can connection to the bus (socketcan allows several sockets;
  the simulation's hub several clients) with ``receive_own_messages`` where the interface can,
  watches SYNC itself (:class:`~ff_hwbridge.drive.sync_watch.SyncWatch` fed by its receiver
  thread), places each stamp on the grid (:class:`~ff_hwbridge.drive.placement.GridPlacement`),
  and runs the :class:`~ff_hwbridge.drive.cycle.CycleScheduler`: safety clamp
  (:class:`~ff_hwbridge.drive.safety.SafetyGuard`: ±limit A, NaN → 0 A), units (raw 0x6071 ‰ /
  0x2030 mA) and RPDO1 (controlword + setpoint, CiA 402) for the right cycle; every SYNC it
  sees opens a cycle in which an enabled drive gets its RPDO1 once (``_on_cycle``): the value in
  force for that cycle again when no new setpoint went out (or, with ``setpoint_lead``, was
  scheduled) for it; the drive's interpolation-period supervision (0x60C2, EMCY 0x8250) is
  what stops a drive whose player froze;
- what it may send comes from the master through shared memory (:meth:`EposMaster.gate`: per
  joint the controlword and whether a current may be sent; the master updates it before it
  sends a new controlword or its safe-state reaction), so the child never re-enables a drive
  the master stops and sends 0 A while the safe state is latched;
- the bridge's process only feeds it (``submit`` → a pipe) and reports: applied setpoints,
  missed cycles, faults and the statistics come back over the pipe. A fault the child reports
  (a miss beyond ``missed_cycle_tolerance``, a setpoint that cannot be placed, a failing send)
  latches the master's safe state with its reason; a child that dies or stops reporting for
  ``DEAD_AFTER`` s latches it too (the drive stops by itself a cycle or two after the last
  RPDO: EMCY 0x8250);
- a safe state or fault reset raises the gate's reset epoch (wall ns): the child forgets the
  value in force (0 until a new setpoint), drops queued setpoints and ignores any stamped
  before the epoch.

The master keeps the state machine, the watchdogs and the reactions; while the player owns an
enabled drive it sends RPDO1 with 0 current only and no refresh of its own
(``EposMaster.external_player``).
"""
from __future__ import annotations

import logging
import multiprocessing as mp
import struct
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable, Optional, Self, Sequence

import can

from ff_hwbridge.drive.bus import send_at
from ff_hwbridge.drive.cycle import CycleScheduler, Resolved
from ff_hwbridge.drive.epos import ECHO_INTERFACES, SYNC_COB_ID, EposMaster
from ff_hwbridge.drive.placement import GridPlacement
from ff_hwbridge.drive.player import MAX_REPORTS, AppliedSetpoint, PlayerBase, PlayerConfig, SetpointPlayer
from ff_hwbridge.drive.safety import SafetyGuard
from ff_hwbridge.drive.realtime import SWITCH_INTERVAL, IdleCollector, RealtimeConfig, setup_process, use_fifo
from ff_hwbridge.drive.scheduler import SwitchStats
from ff_hwbridge.protocol.epos_od import rpdo_layout, struct_format
from ff_hwbridge.protocol.units import DriveUnits

log = logging.getLogger(__name__)

__all__ = ["ProcessPlayer", "make_player"]

STATUS_PERIOD = 0.02      # s, the child's status report (pending, heartbeat)
ECHO_KEEP = 4096          # echoes remembered per joint (their numbers and bus instants)
ECHO_MATCH_NS = 2_000     # a scheduled frame's echo carries its instant (float s: within this)
STATS_PERIOD = 0.25       # s, ... with statistics refreshed this often
DEAD_AFTER = 2.0          # s without a status report: the player process counts as dead
START_TIMEOUT = 30.0      # s for the child to import, open the bus and report ready


def make_player(master: EposMaster, config: Optional[PlayerConfig] = None) -> Any:
    """The player ``master.config`` asks for: :class:`ProcessPlayer` with ``player_process``
    and synchronous setpoints, else an in-process :class:`SetpointPlayer`."""
    if master.config.player_process and master.config.synchronous:
        return ProcessPlayer(master, config)
    return SetpointPlayer(master, config)


@dataclass(frozen=True)
class _Joint:
    node_id: int
    units: DriveUnits
    limit: float              # A
    rx_fmt: str               # RPDO1 struct format (controlword, setpoint)


@dataclass(frozen=True)
class _Spec:
    bus: dict
    echo: bool
    joints: tuple[_Joint, ...]
    period_s: float
    cycle_tolerance: float
    missed_tolerance: int
    rt_priority: int
    setpoint_timeout: float
    stall_dump: float = 0.0
    lead: float = 0.0         # s: setpoints handed to the bus's transmit schedule this early


# --- the child ------------------------------------------------------------------------------------
class _Child:
    """What runs in the player process (see the module docstring)."""

    def __init__(self, spec: _Spec, conn: Any, gate: Any, epoch: Any = None) -> None:
        from ff_hwbridge.drive.bus import open_bus
        from ff_hwbridge.drive.sync_watch import SyncWatch

        self.spec, self.conn, self.gate = spec, conn, gate
        self.epoch_ref = epoch                # shared 64-bit value: the master's reset epoch (ns)
        self.n = len(spec.joints)
        self._conn_lock = threading.Lock()
        self._send_lock = threading.Lock()
        cfg = dict(spec.bus)
        if spec.echo:
            cfg["receive_own_messages"] = True
        # only SYNC and the setpoint RPDOs (our echoes) are of interest here; given at open, the
        # simulation's hub applies them on its side too and sends this process nothing else
        # (at 1 kHz SYNC that spares it and the hub ~2000 TPDO frames a second)
        ids = [SYNC_COB_ID] + [0x200 + j.node_id for j in spec.joints]
        filters = [can.typechecking.CanFilter(can_id=i, can_mask=0x7FF) for i in ids]
        cfg["can_filters"] = filters
        self.bus = open_bus(cfg)
        try:
            self.bus.set_filters(filters)
        except (NotImplementedError, can.CanError, AttributeError):
            pass
        self.watch = SyncWatch(spec.period_s)
        self.guard = SafetyGuard([j.limit for j in spec.joints], spec.setpoint_timeout)
        self.rx_ids = {0x200 + j.node_id: i for i, j in enumerate(spec.joints)}
        self.tx_seq = [0] * self.n
        self.echo_seq = [0] * self.n
        # per joint, the frames handed to the bus not yet echoed: [tx number, data, scheduled
        # wall ns (0: sent at once)]
        self.sent_data: list[deque[list]] = [deque(maxlen=1024) for _ in range(self.n)]
        # per joint: tx number of an echoed frame -> its bus instant (wall ns), the latest ECHO_KEEP
        self.echo_log: list[dict[int, int]] = [{} for _ in range(self.n)]
        self.last_frame: list[Optional[bytes]] = [None] * self.n
        self.raw = [0] * self.n               # the latest setpoint handed to the bus, per joint
        # per joint: (SYNC count of the cycle a frame lies in, its raw setpoint), sorted, and the
        # value in force before the oldest kept: what each cycle's RPDO repeats
        self.planned: list[list[tuple[int, int]]] = [[] for _ in range(self.n)]
        self.base = [0] * self.n
        self.repeats = 0                      # RPDOs repeated in a cycle without a new one
        self.repeats_late = 0                 # with a lead: cycles whose repeat came too late
        self.epoch = 0                        # the gate's reset epoch last acted on (wall ns)
        self.received = 0
        self.stopped = threading.Event()
        self.sched = CycleScheduler(self.watch, self._send, self._report, echo_time=self._echo_time,
                                    prepare=self._prepare, on_fault=self._fault,
                                    tolerance=spec.cycle_tolerance,
                                    missed_tolerance=spec.missed_tolerance,
                                    rt_priority=spec.rt_priority, name="ff-player-process",
                                    stall_dump=spec.stall_dump, lead=spec.lead)
        self.placement = GridPlacement(self.sched.grid)
        self.rx_rt = False
        self.watch.add_listener(self._on_cycle)

    def tell(self, *msg: Any) -> None:
        with self._conn_lock:
            try:
                self.conn.send(msg)
            except (OSError, EOFError, BrokenPipeError):
                self.stopped.set()

    # gate in shared memory: [cw_0, ok_0, cw_1, ok_1, ..., latched]; reset epoch apart
    def _gate(self, i: int) -> tuple[int, bool]:
        return int(self.gate[2 * i]), bool(self.gate[2 * i + 1]) and not self.gate[2 * self.n]

    def _reset_epoch(self) -> int:
        """Wall ns of the latest safe state / fault reset (0: none): setpoints stamped before it
        are never sent, and the value in force was 0 from it on."""
        return int(self.epoch_ref.value) if self.epoch_ref is not None else 0

    def _check_epoch(self) -> int:
        """Act on a new reset epoch (any thread): forget the value in force, drop what is
        queued. Returns the epoch."""
        e = self._reset_epoch()
        if e != self.epoch:
            with self._send_lock:
                if e != self.epoch:
                    self.epoch = e
                    for i in range(self.n):
                        self._forget(i)
            self.sched.clear()
        return e

    def _forget(self, i: int) -> None:
        """Joint ``i``'s value in force is 0 from now on (call with ``_send_lock`` held)."""
        self.planned[i].clear()
        self.base[i] = 0
        self.raw[i] = 0

    def _prepare(self, q: tuple) -> tuple:
        """Safety clamp (±limit A, NaN → 0 A) and units; 0 A while the bridge's safe state is
        latched (the gate's last entry) or for a setpoint stamped before the reset epoch."""
        cmd = self.guard.filter(q[1])
        if self.gate[2 * self.n]:
            return q, (0,) * self.n, "safe state latched by the bridge", True
        if q[0] < self._check_epoch():
            return q, (0,) * self.n, "stamped before the latest safe state / fault reset", True
        raws = tuple(j.units.amps_to_setpoint(float(a), limit=j.limit)
                     for j, a in zip(self.spec.joints, cmd.currents))
        return q, raws, cmd.reason, cmd.latched

    def _frame(self, i: int, raw: int) -> Optional[bytes]:
        cw, ok = self._gate(i)
        if not ok:
            return None                       # the master owns this drive's RPDO now
        return struct.pack(self.spec.joints[i].rx_fmt, cw & 0xFFFF, int(raw))

    def _cycle_of(self, at_ns: Optional[int]) -> int:
        """SYNC count of the cycle a frame lies in that is sent now (``at_ns`` None: the cycle
        the latest SYNC seen opened) or scheduled for wall instant ``at_ns``."""
        g = self.watch.grid()
        if g is None:
            return 0
        ev, nominal = g
        if at_ns is None:
            return ev.count
        p = self.watch.period_ns
        return ev.count + (at_ns - nominal) // p

    def _note(self, i: int, cycle: int, raw: int, now: bool) -> None:
        """Record joint ``i``'s frame in ``cycle`` (call with ``_send_lock`` held); a frame
        sent at once on a bus with a transmit schedule replaced the ones scheduled after it."""
        plan = self.planned[i]
        if now and self.spec.lead > 0:
            while plan and plan[-1][0] > cycle:
                plan.pop()
        k = len(plan)
        while k and plan[k - 1][0] > cycle:
            k -= 1
        if k and plan[k - 1][0] == cycle:
            plan[k - 1] = (cycle, int(raw))     # the later frame in one cycle is latched
        else:
            plan.insert(k, (cycle, int(raw)))

    def _in_force(self, i: int, cycle: int) -> int:
        """Joint ``i``'s raw setpoint in force in ``cycle`` (the last frame at or before it)."""
        for c, raw in reversed(self.planned[i]):
            if c <= cycle:
                return raw
        return self.base[i]

    def _tx(self, i: int, data: bytes, raw: int, at_ns: Optional[int] = None) -> None:
        """Send RPDO1 ``data`` (setpoint ``raw``) to joint ``i``, at once or (``at_ns``, wall ns)
        through the bus's transmit schedule; call with ``_send_lock`` held, so that a repeat
        never goes out between a setpoint and the record of it: a repeat of the previous
        setpoint after a new one would be what the drive latches at the SYNC."""
        entry = [self.tx_seq[i] + 1, data, int(at_ns or 0)]
        self.sent_data[i].append(entry)
        msg = can.Message(arbitration_id=0x200 + self.spec.joints[i].node_id, data=data,
                          is_extended_id=False)
        scheduled = False
        if at_ns is not None:
            scheduled = send_at(self.bus, msg, at_ns)
            if not scheduled:
                entry[2] = 0                    # its instant had passed: sent now
        else:
            self.bus.send(msg)
        self.tx_seq[i] += 1
        self.last_frame[i] = data
        self.raw[i] = int(raw)
        self._note(i, self._cycle_of(at_ns if scheduled else None), raw, not scheduled)

    def _on_cycle(self, ev: Any) -> None:
        """A SYNC seen (receiver thread; ``ev`` a SyncEvent): the cycle it opens gets each
        enabled drive's RPDO1 once: the value in force for it again when no frame went out (or
        is scheduled) in it. With a lead the repeat is scheduled mid-cycle (a frame sent at
        once would replace the setpoints scheduled after it)."""
        self._check_epoch()
        lead = self.spec.lead > 0
        for i in range(self.n):
            with self._send_lock:
                cw, ok = self._gate(i)
                if not ok:
                    self._forget(i)             # the master owns the RPDO; 0 when it hands back
                    continue
                plan = self.planned[i]
                while len(plan) > 1 and plan[0][0] < ev.count - 1:
                    self.base[i] = plan.pop(0)[1]
                if any(c == ev.count for c, _ in plan):
                    continue
                raw = self._in_force(i, ev.count)
                data = struct.pack(self.spec.joints[i].rx_fmt, cw & 0xFFFF, raw)
                at_ns: Optional[int] = None
                if lead:
                    g = self.watch.grid()
                    if g is None:
                        continue
                    p = self.watch.period_ns
                    at_ns = max(g[1] + p // 2, time.time_ns() + 200_000)
                    if at_ns > g[1] + p - p // 10:
                        self.repeats_late += 1    # too late to schedule within its cycle
                        continue
                self.repeats += 1
                self._tx(i, data, raw, at_ns)

    def _send(self, stamp_ns: int, prepared: tuple,
              at_ns: Optional[int] = None) -> tuple[Optional[tuple[int, ...]], Any]:
        q, raws, reason, latched = prepared
        marks: list[int] = []
        echo = self.spec.echo
        for i, raw in enumerate(raws):
            with self._send_lock:
                data = self._frame(i, raw)
                if data is None:
                    self.raw[i] = 0
                    echo = False
                    continue
                self._tx(i, data, raw, at_ns)
                marks.append(self.tx_seq[i])
        currents = tuple(j.units.setpoint_to_amps(r) for j, r in zip(self.spec.joints, self.raw))
        return (tuple(marks) if echo else None), (q, currents, reason, latched)

    def _report(self, r: Resolved) -> None:
        q, currents, reason, latched = r.token
        self.tell("applied", r.applied_ns, r.stamp_ns, currents, q[2], q[3], q[4], reason, latched,
                  r.sent_ns, r.missed_cycles)

    def _fault(self, reason: str) -> None:
        self.tell("fault", reason)

    def _echo_time(self, marks: Sequence[int]) -> Optional[int]:
        t = 0
        for i, m in enumerate(marks):
            hit = self.echo_log[i].get(m)
            if hit is None:
                return None
            t = max(t, hit)
        return t

    # --- threads ----------------------------------------------------------------------------
    def receive(self) -> None:
        if self.spec.rt_priority > 0:
            self.rx_rt = use_fifo(self.spec.rt_priority, "player process bus receiver")
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
                    self._fault(f"setpoint player process: the bus is gone ({type(exc).__name__}: "
                                f"{exc})")
                    self.stopped.set()
                    return
                time.sleep(0.01)
                continue
            if msg is None:
                continue
            cid = msg.arbitration_id
            if cid == SYNC_COB_ID:
                self.watch.observe(msg.timestamp, tuple(self.echo_seq) if self.spec.echo else None)
            elif cid in self.rx_ids:
                i = self.rx_ids[cid]
                ts = int(round(msg.timestamp * 1e9)) if msg.timestamp else time.time_ns()
                seq = self._own(self.sent_data[i], bytes(msg.data), ts)
                if seq > 0:                           # our own frame, echoed by the bus
                    self.echo_seq[i] += 1
                    log_ = self.echo_log[i]
                    log_[seq] = ts
                    log_.pop(seq - ECHO_KEEP, None)

    def _own(self, sent: "deque[list]", data: bytes, ts_ns: int) -> int:
        """The tx number of the frame an echo (``data``, bus instant ``ts_ns``) is of, removed
        from ``sent`` (0: not ours). Without a transmit schedule the bus echoes in send order.
        With one, frames go on the bus in the order of their instants, not of their hand-over
        (a setpoint scheduled cycles ahead, the repeats of the cycles before it handed over
        later), and a frame sent at once drops those scheduled after it, which never echo: a
        scheduled frame is known by its instant (the echo carries it), one sent at once is the
        oldest of its data; entries scheduled well before this echo are gone."""
        if not sent:
            return 0
        if self.spec.lead <= 0:
            if sent[0][1] == data:
                return int(sent.popleft()[0])
            return 0
        hit = None
        for e in sent:
            if e[1] != data:
                continue
            if e[2] and abs(e[2] - ts_ns) <= ECHO_MATCH_NS:
                hit = e
                break
            if not e[2] and hit is None:
                hit = e
        if hit is None:
            return 0
        sent.remove(hit)
        stale = ts_ns - 2 * self.watch.period_ns
        while sent and 0 < sent[0][2] < stale:
            sent.popleft()                            # dropped by the bus: never echoed
        return int(hit[0])

    def status(self) -> None:
        if self.spec.rt_priority > 0:         # the heartbeat to the bridge
            use_fifo(self.spec.rt_priority, "player process status")
        idle_gc = IdleCollector(lambda: self.sched.pending == 0)
        figures_at, was_pending = 0.0, False
        while not self.stopped.wait(STATUS_PERIOD):
            idle_gc.tick()
            self._check_epoch()
            now = time.monotonic()
            pending = self.sched.pending
            # percentiles: numpy, but not for free; fresh at once when a stream has ended
            if now - figures_at >= STATS_PERIOD or (was_pending and not pending):
                figures_at = now
                s, c, w = self.sched.stats(), self.sched.cycle_stats(), self.watch.stats()
            was_pending = pending > 0
            g = self.sched.grid()
            self.tell("status", self.received, pending, s, c, w.as_dict(), g,
                      int(self.sched.rt_active and (self.rx_rt or self.spec.rt_priority <= 0)),
                      self.sched.stale, self.sched.stale_stops, self.sched.errors,
                      self.repeats, self.repeats_late)

    def run(self) -> None:
        # the heap built so far frozen (later full collections only while nothing is pending:
        # ``status``), and no thread here holding the GIL at normal priority
        setup_process(RealtimeConfig(priority=max(0, self.spec.rt_priority - 1), switch_interval=SWITCH_INTERVAL,
                                     freeze_gc=True), "setpoint player process")
        threading.Thread(target=self.receive, name="ff-player-rx", daemon=True).start()
        threading.Thread(target=self.status, name="ff-player-status", daemon=True).start()
        self.sched.start()
        self.tell("ready")
        try:
            while not self.stopped.is_set():
                try:
                    msg = self.conn.recv()
                except (EOFError, OSError):
                    break
                kind = msg[0]
                if kind == "sp":
                    _, stamp, amps, seq, pid, last, stop = msg
                    self.received += 1
                    if stamp < self._check_epoch():
                        continue              # from before the latest safe state / reset
                    placed = self.placement.place(stamp, pid, seq)
                    self.sched.submit(placed, (stamp, amps, seq, pid, last), stop=stop)
                elif kind == "clear":
                    self.sched.clear()
                elif kind == "reset_stats":
                    self.sched.reset_stats()
                    self.watch.reset_stats()
                elif kind == "stop":
                    break
        finally:
            self.stopped.set()
            self.sched.close()
            try:
                self.bus.shutdown()
            except (OSError, can.CanError) as exc:
                # the receiver thread may be reading the connection as it closes, or the bus
                # went first (the hub stopped): nothing is left to send on it
                log.debug("closing the player's bus: %s", exc)


def _child_main(spec: _Spec, conn: Any, gate: Any, epoch: Any) -> None:
    logging.basicConfig(level=logging.WARNING, format="%(name)s: %(message)s")
    try:
        child = _Child(spec, conn, gate, epoch)
    except Exception as exc:  # noqa: BLE001 - told to the parent, which latches the safe state
        conn.send(("fault", f"setpoint player process could not start: {type(exc).__name__}: {exc}"))
        return
    child.run()


# --- the bridge's side --------------------------------------------------------------------------
class ProcessPlayer(PlayerBase):
    """:class:`SetpointPlayer`'s interface, played by a child process (module docstring)."""

    synchronous = True

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

    # --- control ------------------------------------------------------------------------------
    def _spec(self) -> _Spec:
        cfg = self.master.config
        bus = cfg.bus.as_dict()
        joints = tuple(_Joint(j.node_id, u, float(j.current_limit), struct_format(rpdo_layout(u.family)))
                       for j, u in zip(cfg.joints, self.master.units))
        return _Spec(bus, bus.get("interface") in ECHO_INTERFACES, joints, float(cfg.sync_period),
                     self.config.cycle_tolerance, int(cfg.missed_cycle_tolerance),
                     int(self.config.rt_priority), float(cfg.setpoint_timeout),
                     float(self.config.stall_dump), float(cfg.setpoint_lead))

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
        self._proc = self._ctx.Process(target=_child_main, args=(self._spec(), child, self._gate, self._epoch),
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
        self._tell("sp", int(stamp_ns), amps, int(seq), str(profile_id), bool(last),
                   all(c == 0.0 for c in amps))

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
                (_, applied, stamp, currents, seq, pid, last, reason, latched, sent, missed) = msg
                self._reports.append(AppliedSetpoint(applied, stamp, tuple(currents), seq, pid, last,
                                                     reason, latched, sent, missed))
                self.records_.append((stamp, applied))
                if last:
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
        return None if st is None else st[6]

    def diagnostics(self) -> dict[str, float]:
        """As :meth:`SetpointPlayer.diagnostics`, plus ``player_process`` 1 and its pid."""
        out = self._switch_diagnostics()
        out.update({"scheduler_realtime": 0, "synchronous": 1, "player_process": 1,
                    "player_pid": float(self.pid or 0)})
        st = self._status
        if st is not None:
            c, w = st[4], st[5]
            out.update({"scheduler_realtime": st[7], "missed_setpoints": c.missed,
                        "missed_cycles_max": c.missed_max_cycles, "superseded_setpoints": c.superseded,
                        "send_after_sync_p99_us": c.send_after_sync_p99_us,
                        "sync_count": w["count"], "sync_period_us": w["period_us"],
                        "sync_jitter_p99_us": w["jitter_p99_us"], "sync_jitter_max_us": w["jitter_max_us"],
                        "sync_missing": w["missing"], "sync_age_ms": w["age_ms"],
                        "stale_setpoints": st[8], "stale_stops": st[9], "player_errors": st[10],
                        "cycle_repeats": st[11], "cycle_repeats_late": st[12]})
        return out

"""Maxon EPOS4 / EPOS2 CANopen master on the ``canopen`` library (no rclpy).

One :class:`EposMaster` drives a group of joints (one EPOS each) on one python-can bus:

- ``connect()``   open the bus (any python-can interface, by configuration), a canopen Network,
                  one RemoteNode per joint (object dictionary built in code, ``epos_od.py``),
                  heartbeat / EMCY / TPDO listeners.
- ``configure()`` per drive: NMT reset communication + wait for boot-up, SDO configuration
                  (0x6040 = 0 disable voltage first; 0x6060 mode: EPOS4 10 = CST, EPOS2 -3 =
                  current mode; 0x1017 heartbeat; optional 0x1016 consumer of a master heartbeat;
                  motor data read/limit write), PDO mapping (RPDO1 controlword + setpoint, type
                  255; TPDO1 statusword + position, TPDO2 velocity + current, type 1), NMT start;
                  then the SYNC producer and the monitor thread (heartbeat timeout, TPDO
                  silence, setpoint watchdog).
- ``enable()`` / ``disable()`` / ``quick_stop()`` / ``fault_reset()`` set a *target* CiA 402
                  state; the state is driven through the RPDO controlword one non-blocking step
                  per received statusword (``cia402.next_controlword``). ``wait_for_state()`` is a
                  separate, optional blocking helper.
- ``command_currents(amps)`` sends one RPDO per joint; every command goes through the
                  :class:`~ff_hwbridge.drive.safety.SafetyGuard` (clamp, latch) and is clamped again in
                  raw drive units. ``prepare_currents`` + ``send_prepared`` split it so that a
                  player (``drive.player.SetpointPlayer``) does the work before a stamp and only sends at it.
- The cycle contract (CiA 402 cyclic synchronous modes): every SYNC seen opens a cycle in
                  which each operational drive gets its RPDO1 once, the value in force repeated
                  when nothing new went out in it (``_on_cycle``, the bus receiver's thread, user
                  space: a frozen process falls silent and the drive's interpolation-period
                  supervision, EMCY 0x8250, stops it). A player in another process repeats an
                  enabled drive's RPDO itself. ``on_receipt`` also: while a drive's state differs
                  from its target the controlword is repeated every 5 ms, and every RPDO is
                  refreshed at least every 50 ms (when no SYNC is seen).
- Faults (EMCY, drive in Fault, heartbeat loss, TPDO silence, boot-up or NMT state other than
                  OPERATIONAL in the heartbeat, setpoint watchdog) latch the safe state: zero
                  current, quick stop (or disable voltage), reason kept until ``fault_reset()``
                  (which sets up a rebooted node again).

canopen's BaseNode402 is not used (it blocks waiting for statuswords).

Command line: ``ff-epos`` (``ff_hwbridge.cli.epos``).
"""
from __future__ import annotations

import logging
import math
import struct
import threading
import time
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Optional, Sequence

import canopen
import numpy as np

from ff_hwbridge.drive.bus import open_bus
from ff_hwbridge.drive.config import BridgeConfig, JointConfig
from ff_hwbridge.drive.feedback import JointFeedback, SamplePairing
from ff_hwbridge.drive.heartbeat import HeartbeatSender
from ff_hwbridge.drive.realtime import use_fifo
from ff_hwbridge.drive.safety import SafeCommand, SafetyGuard
from ff_hwbridge.drive.sync_sender import SyncSender
from ff_hwbridge.drive.sync_watch import SyncWatch
from ff_hwbridge.protocol import cia402
from ff_hwbridge.protocol.cia402 import SW_INTERNAL_LIMIT, SW_WARNING, State
from ff_hwbridge.protocol.epos_errors import EMCY_CLASSES, describe  # noqa: F401  (EMCY_CLASSES re-exported)
from ff_hwbridge.protocol.epos_od import (DEVICE_PROFILE_402, MAXON_VENDOR_ID, RPDO_SETPOINT, TPDO_MOTION,
                                          TPDO_STATUS, VELOCITY_UNIT_RPM, build_object_dictionary,
                                          rpdo_layout, struct_format, tpdo1_layout, tpdo2_layout)
from ff_hwbridge.protocol.units import DriveUnits

log = logging.getLogger(__name__)

NMT_STATES = {0x00: "BOOTUP", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE-OPERATIONAL"}
# python-can interfaces that echo the bus's own frames back with their bus timestamp
# (``receive_own_messages``): the master sees its SYNC and which RPDOs were on the bus before it
ECHO_INTERFACES = frozenset({"socketcan", "virtual", "remote", "kvaser"})
SYNC_COB_ID = 0x80               # CiA 301 default 0x1005 COB-ID SYNC
# SDO abort codes meaning "this drive has no such object" (CiA 301)
ABORT_NO_OBJECT = (0x06020000, 0x06090011)
# objects the master writes only where a drive has them (maxon's EPOS4 EDS lacks the RxPDO event
# timer): an EDS without them is accepted
OPTIONAL_SUBS = frozenset({(0x1400, 5)})


# s, setpoint_timing on_receipt only (sync: one RPDO per SYNC cycle): repeat the controlword
# while the drive's state differs from the target; refresh any RPDO at least this often (both
# are idempotent for the drive: a fault reset needs a rising edge)
RESEND_PERIOD = 0.005
REFRESH_PERIOD = 0.05



@dataclass(frozen=True)
class PreparedCommand:
    """Currents that passed the guard (``command``) and their raw drive setpoints, per joint."""

    command: SafeCommand
    raw: tuple[int, ...]


class EposError(RuntimeError):
    """A drive that cannot be reached or configured; the message names the node and the step."""


@dataclass
class _Drive:
    cfg: JointConfig
    units: DriveUnits
    node: Any = None
    rx_fmt: str = "<Hh"
    tx1_fmt: str = "<Hi"
    tx2_fmt: str = "<ii"
    raw_limit: int = 0
    target: State = State.SWITCH_ON_DISABLED
    controlword: int = 0
    setpoint: int = 0
    feedback: JointFeedback = field(default_factory=JointFeedback)
    nmt_state: Optional[str] = None
    last_heartbeat: Optional[float] = None
    boot_count: int = 0
    last_boot: float = 0.0
    reset_until: float = 0.0      # monotonic s: Fault is expected (fault reset in progress)
    operational: bool = False
    seen_operational: bool = False
    tpdo_seen: bool = False
    last_tx: float = 0.0          # monotonic s of the latest RPDO
    cycle_sent: int = -1          # SYNC count (SyncWatch) seen when the latest RPDO was sent
    cycle_repeats: int = 0        # RPDOs repeated because nothing new went out in a cycle
    tx_seq: int = 0               # setpoint RPDOs handed to the bus
    tx_failing: int = 0           # setpoint RPDOs failed since the last that went through
    pairing: Optional[SamplePairing] = None   # TPDO1 <-> SYNC (the sample instant)
    echo_seq: int = 0             # of those, echoed back by the bus (receive_own_messages)
    echo_log: deque = field(default_factory=lambda: deque(maxlen=1024))  # (echo_seq, bus ns)
    emcy: deque = field(default_factory=lambda: deque(maxlen=20))   # recent EMCY texts
    warnings: deque = field(default_factory=lambda: deque(maxlen=20))  # recent warning EMCYs
    history_wanted: bool = False  # read 0x1003 / 0x603F (monitor thread) after a fault
    error_history: str = ""       # decoded 0x1003 / 0x603F, newest first
    notes: list = field(default_factory=list)   # drive settings that could not be applied
    envelope_armed: bool = True   # False after a fault reset outside the envelope
    consumer_armed: bool = False  # 0x1016:01 consumes this master's heartbeat (disarmed on exit)
    limited_count: int = 0        # TPDO1s with statusword bit 11 (internal limit) in this motion
    limited_first_ns: int = 0     # wall ns (sample instant) of the first of them; 0: none

    @property
    def node_id(self) -> int:
        return self.cfg.node_id


class EposMaster:
    """The CANopen master for one drive group (see the module docstring)."""

    def __init__(self, config: BridgeConfig, clock: Callable[[], float] = time.monotonic,
                 on_fault: Optional[Callable[[str], None]] = None) -> None:
        self.config = config
        self.clock = clock
        self.guard = SafetyGuard(config.current_limits, config.setpoint_timeout)
        self._fault_listeners: list[Callable[[str], None]] = [] if on_fault is None else [on_fault]
        self.pending_fn: Callable[[], bool] = lambda: False
        self.network: Optional[canopen.Network] = None
        self._bus_lost_told = False     # the notifier's exception was reported (once per connection)
        self._drives = [_Drive(cfg=j, units=j.units) for j in config.joints]
        self._send_lock = threading.RLock()
        self._monitor: Optional[threading.Thread] = None
        self._monitor_stop = threading.Event()
        self._sync_running = False
        self._sync_sender: Optional[SyncSender] = None
        self._fb_lock = threading.Lock()
        self._master_hb: Any = None
        self._configured = False
        self._sdo_lock = threading.RLock()     # one SDO user at a time (configure, error history)
        self.events: deque[tuple[float, str]] = deque(maxlen=200)   # (monotonic s, text)
        self.tx_errors = 0
        self.sync_watch = SyncWatch(config.sync_period)
        self.echo = False                 # the bus echoes our frames (set at connect)
        # a setpoint player in another process owns the currents (player_process): this master
        # then sends RPDO1 with 0 current only (state machine, reactions) and leaves the
        # refresh of an enabled drive's RPDO to the player; ``gate_listener()`` is called
        # whenever what the player may send (``gate()``) may have changed
        self.external_player = False
        self.gate_listener: Optional[Callable[[], None]] = None
        self._sync_expected_since: Optional[float] = None   # monotonic s: SYNC must come
        # wall ns (time.time_ns, the setpoints' stamp clock) of the latest safe state or fault
        # reset: the current is 0 from then on until a setpoint stamped after it
        self.reset_epoch_ns = 0
        # the cycle contract: every SYNC seen, each operational drive's RPDO goes out once
        self.sync_watch.add_listener(self._on_cycle)

    # --- properties ---------------------------------------------------------------------------
    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.config.joint_names

    @property
    def units(self) -> tuple[DriveUnits, ...]:
        return tuple(d.units for d in self._drives)

    @property
    def latched(self) -> bool:
        return self.guard.latched

    @property
    def fault_reason(self) -> Optional[str]:
        return self.guard.reason

    def states(self) -> list[Optional[State]]:
        return [d.feedback.state for d in self._drives]

    def heartbeats_operational(self) -> list[bool]:
        """Per joint: an OPERATIONAL heartbeat arrived since the NMT start (from then on a
        heartbeat loss is judged against ``heartbeat_timeout``, before it ``state_timeout``)."""
        return [d.seen_operational for d in self._drives]

    def feedback(self) -> list[JointFeedback]:
        """The latest feedback per joint (immutable snapshots, each from one TPDO1 / TPDO2)."""
        return [d.feedback for d in self._drives]

    def _publish(self, d: _Drive, **changes: Any) -> JointFeedback:
        """Swap in a new feedback snapshot of ``d`` with ``changes``."""
        with self._fb_lock:
            d.feedback = fb = replace(d.feedback, **changes)
        return fb

    def status(self) -> dict[str, Any]:
        """A flat summary for diagnostics."""
        now = self.clock()
        out: dict[str, Any] = {"safe_state": self.guard.latched,
                               "reason": self.guard.reason or "",
                               "configured": self._configured, "tx_errors": self.tx_errors}
        for d in self._drives:
            p = f"{d.cfg.name}."
            out[p + "node_id"] = d.node_id
            out[p + "state"] = d.feedback.state.value if d.feedback.state else "unknown"
            out[p + "target"] = d.target.value
            out[p + "statusword"] = f"0x{d.feedback.statusword:04X}"
            out[p + "nmt"] = d.nmt_state or "unknown"
            out[p + "heartbeat_age_ms"] = (round((now - d.last_heartbeat) * 1000.0, 1)
                                           if d.last_heartbeat is not None else -1.0)
            out[p + "setpoint_raw"] = d.setpoint
            out[p + "cycle_repeats"] = d.cycle_repeats     # RPDOs repeating the value in force
            out[p + "last_emcy"] = d.emcy[-1] if d.emcy else ""
            sw = d.feedback.statusword
            out[p + "warning"] = bool(sw & SW_WARNING)                # statusword bit 7
            out[p + "internal_limit_active"] = bool(sw & SW_INTERNAL_LIMIT)   # bit 11
            # latched per motion: the drive clipped the command (a failed feedforward move)
            out[p + "motion_limited_count"] = d.limited_count
            out[p + "motion_limited_first_ns"] = d.limited_first_ns
            out[p + "last_warning"] = d.warnings[-1] if d.warnings else ""
            out[p + "error_history"] = d.error_history
            if d.notes:
                out[p + "drive_notes"] = "; ".join(d.notes)
        return out

    # --- connection -----------------------------------------------------------------------------
    def connect(self, bus: Any = None) -> None:
        """Open the bus (or use ``bus``, a python-can bus) and add one RemoteNode per joint."""
        if self.network is not None:
            return
        ods = [self._object_dictionary(d) for d in self._drives]    # a bad EDS: nothing opened
        if bus is None:
            cfg = self.config.bus.as_dict()
            if self.config.synchronous and cfg["interface"] in ECHO_INTERFACES:
                cfg.setdefault("receive_own_messages", True)
            self.echo = bool(cfg.get("receive_own_messages", False))
            bus = open_bus(cfg)   # checks loopback-only remotes
        else:
            self.echo = bool(getattr(bus, "receive_own_messages", False)
                             or getattr(bus, "_recv_own", False))
        net = canopen.Network(bus)
        net.NOTIFIER_CYCLE = 0.1        # bounds how long disconnect() waits for the receiver
        net.connect()
        self.network = net
        self._bus_lost_told = False
        for d, od in zip(self._drives, ods):
            node = canopen.RemoteNode(d.node_id, od)
            node.sdo.RESPONSE_TIMEOUT = self.config.sdo_timeout
            node.sdo.MAX_RETRIES = 2            # a drive busy right after boot-up may answer late
            net.add_node(node)
            d.node = node
            d.rx_fmt = struct_format(rpdo_layout(d.units.family))
            d.tx1_fmt = struct_format(tpdo1_layout(d.units.family))
            d.tx2_fmt = struct_format(tpdo2_layout(d.units.family))
            d.raw_limit = d.units.setpoint_limit(d.cfg.current_limit)
            net.subscribe(0x700 + d.node_id, self._make_heartbeat_cb(d))
            node.emcy.add_callback(self._make_emcy_cb(d))
        net.subscribe(SYNC_COB_ID, self._on_sync)

    def disconnect(self) -> None:
        """Zero current, disable voltage, disarm the drives' consumer of this master's heartbeat
        (0x1016:01 = 0: a clean exit is no heartbeat loss, and the next start finds the drive
        out of Fault), stop SYNC and the monitor, close the bus (idempotent)."""
        self._stop_monitor()
        if self.network is None:
            return
        try:
            for d in self._drives:
                d.target = State.SWITCH_ON_DISABLED
                if d.operational:
                    self._send_rpdo(d, cia402.CONTROLWORD[cia402.Command.DISABLE_VOLTAGE], 0)
            if self.config.synchronous and self.sync_expected:
                # a synchronous RPDO takes effect at the next SYNC: keep SYNC for two more
                time.sleep(2.5 * self.config.sync_period)
            self.disarm_heartbeat_consumers()
        finally:
            self.stop_sync()
            self.stop_master_heartbeat()
            for d in self._drives:
                d.operational = False
            try:
                self.network.disconnect()
            except Exception:  # noqa: BLE001 - best effort on the way out
                log.exception("closing the CAN network")
            self.network = None
            self._configured = False

    close = disconnect

    def disarm_heartbeat_consumers(self) -> list[str]:
        """Write 0x1016:01 = 0 on every drive this master armed to consume its heartbeat (while
        that heartbeat still runs); returns the joints where it failed (logged, never raised:
        a drive that cannot be reached faults 0x8130 as it would for a dead master)."""
        failed = []
        if self.network is None or self._bus_lost_told:
            return [d.cfg.name for d in self._drives if d.consumer_armed]
        for d in self._drives:
            if not d.consumer_armed or d.node is None:
                continue
            try:
                with self._sdo_lock:
                    d.node.sdo[0x1016][1].raw = 0
                d.consumer_armed = False
            except Exception as exc:  # noqa: BLE001 - canopen raises SdoError, CanError, ...
                failed.append(d.cfg.name)
                log.warning("node %d (%s): could not disarm its heartbeat consumer 0x1016:01 (%s); "
                            "it faults 0x8130 once this master's heartbeat stops", d.node_id,
                            d.cfg.name, exc)
        return failed

    def _connected_network(self) -> canopen.Network:
        """The canopen Network; EposError before ``connect()`` / after ``disconnect()``."""
        if self.network is None:
            raise EposError("the CAN network is not connected; call connect() first")
        return self.network

    # --- configuration -------------------------------------------------------------------------
    def configure(self) -> None:
        """SDO/PDO set-up of every drive, NMT start, SYNC and monitoring. EposError on failure."""
        if self.network is None:
            self.connect()
        self._start_master_heartbeat()     # before the drives start watching it
        for d in self._drives:
            self._configure_drive(d)
        self.start_sync()
        self._start_monitor()
        if self.config.rt_priority > 0:
            # the bus receiver writes every SYNC cycle's RPDO (``_on_cycle``): SCHED_FIFO, so that
            # a loaded machine does not hold it off the CPU for a cycle (the drive would fault)
            self.set_receiver_priority(self.config.rt_priority)
        self._configured = True

    def _configure_drive(self, d: _Drive) -> None:
        with self._sdo_lock:
            self._configure_drive_locked(d)

    def _await_boot(self, d: _Drive) -> None:
        """NMT reset communication until a boot-up frame arrives (one every ``boot_timeout`` s,
        ``boot_wait`` s in all): a drive powered late is waited for. EposError when none came."""
        node, nid = d.node, d.node_id
        t0 = self.clock()
        total = max(self.config.boot_wait, self.config.boot_timeout)
        attempt = 0
        while True:
            attempt += 1
            boots = d.boot_count
            node.nmt.send_command(0x82)     # reset communication
            deadline = min(self.clock() + self.config.boot_timeout, t0 + total)
            while d.boot_count == boots and self.clock() < deadline:
                time.sleep(0.002)
            if d.boot_count != boots:
                if attempt > 1:
                    log.warning("node %d (%s) booted after %.1f s (%d NMT resets)", nid,
                                d.cfg.name, self.clock() - t0, attempt)
                return
            if self.clock() >= t0 + total:
                raise EposError(f"node {nid} ({d.cfg.name}): no boot-up frame within {total:g} s "
                                f"({attempt} NMT reset communication(s), one every "
                                f"{self.config.boot_timeout:g} s); check the node id, bitrate, "
                                "wiring / the drive is powered")
            log.warning("node %d (%s): no boot-up frame yet; waiting for the drive (%.1f of %.1f s, "
                        "NMT reset %d)", nid, d.cfg.name, self.clock() - t0, total, attempt)

    def _configure_drive_locked(self, d: _Drive) -> None:
        node, nid, fam = d.node, d.node_id, d.units.family
        d.operational = False
        d.last_heartbeat = None
        d.notes = []
        if self.config.reset_communication:
            self._await_boot(d)

        def sdo_write(index: int, sub: Optional[int], value: int, what: str) -> None:
            try:
                obj = node.sdo[index] if sub is None else node.sdo[index][sub]
                obj.raw = value
            except Exception as exc:  # noqa: BLE001 - canopen raises SdoError, KeyError, CanError
                raise EposError(f"node {nid} ({d.cfg.name}): SDO write {what} = {value} failed: "
                                f"{exc}") from exc

        def sdo_read(index: int, sub: Optional[int], what: str) -> int:
            try:
                obj = node.sdo[index] if sub is None else node.sdo[index][sub]
                return int(obj.raw)
            except Exception as exc:  # noqa: BLE001
                raise EposError(f"node {nid} ({d.cfg.name}): SDO read {what} failed: {exc}") from exc

        def optional(index: int, sub: Optional[int], value: Optional[int], what: str,
                     quiet: bool = False) -> Optional[int]:
            """Write ``value`` (or read, when None); None when the drive has no such object
            (noted in the diagnostics; logged as a warning unless ``quiet``), EposError on any
            other failure."""
            try:
                obj = node.sdo[index] if sub is None else node.sdo[index][sub]
                if value is None:
                    return int(obj.raw)
                obj.raw = value
                return value
            except canopen.SdoAbortedError as exc:
                if exc.code not in ABORT_NO_OBJECT:
                    raise EposError(f"node {nid} ({d.cfg.name}): SDO {what} failed: {exc}") from exc
            except KeyError:
                pass                   # not in the drive's EDS (the object dictionary used)
            note = f"{what}: not on this drive"
            d.notes.append(note)
            log.log(logging.INFO if quiet else logging.WARNING, "node %d (%s): %s", nid, d.cfg.name, note)
            return None

        if self.config.check_identity:
            dev = sdo_read(0x1000, None, "0x1000 device type")
            if dev & 0xFFFF != DEVICE_PROFILE_402:
                raise EposError(f"node {nid} ({d.cfg.name}): device type 0x1000 = 0x{dev:08X} is not "
                                f"a CiA 402 drive (profile {dev & 0xFFFF}, expected 402); check the "
                                "node id")
            vendor = sdo_read(0x1018, 1, "0x1018:01 vendor id")
            if vendor != MAXON_VENDOR_ID:
                raise EposError(f"node {nid} ({d.cfg.name}): vendor id 0x1018:01 = 0x{vendor:08X}, "
                                f"not maxon (0x{MAXON_VENDOR_ID:08X}); check the node id, or set "
                                "check_identity: false for another CiA 402 drive")
        # whatever state a previous master left it in: no current (disable voltage, transition
        # 7/9/10/12), before anything else is changed
        sdo_write(0x6040, None, 0x0000, "0x6040 controlword (disable voltage)")
        mode = d.cfg.mode_of_operation
        sdo_write(0x6060, None, mode, "0x6060 modes of operation")
        shown = sdo_read(0x6061, None, "0x6061 modes of operation display")
        if shown != mode:
            raise EposError(f"node {nid}: drive shows mode {shown} after 0x6060 = {mode}; "
                            f"is it an {fam.upper()} in a state that accepts the mode?")
        sdo_write(0x1017, None, self.config.heartbeat_producer_ms, "0x1017 producer heartbeat (ms)")
        consumer = ((self.config.master_node_id << 16) | self.config.master_heartbeat_timeout_ms
                    if self.config.master_heartbeat_ms else 0)
        sdo_write(0x1016, 1, consumer, "0x1016:01 consumer heartbeat time (master)")
        d.consumer_armed = consumer != 0
        # the drive's own reactions, explicitly (never the factory settings by accident)
        c = self.config
        for index, sub, value, what in ((0x605A, None, c.quick_stop_option, "0x605A quick stop option"),
                                        (0x605E, None, c.fault_reaction_option, "0x605E fault reaction option"),
                                        (0x6007, None, c.abort_connection_option,
                                         "0x6007 abort connection option"),
                                        (0x1029, 1, c.communication_error_behaviour,
                                         "0x1029:01 communication error behaviour")):
            optional(index, sub, value, what)
        self._apply_scaling(d, sdo_read, sdo_write, optional)
        try:
            # synchronous (1): the drive latches the setpoint at the next SYNC; 255: on receipt
            self._map_pdo(node.rpdo[RPDO_SETPOINT], 0x200 + nid, 1 if c.synchronous else 255,
                          rpdo_layout(fam))
            # the feedback: every feedback_every-th SYNC (transmission type 1..240); TxPDO
            # COB-IDs with bit 30 set (no RTR), as maxon's EDS has them (0x40000180 + id)
            self._map_pdo(node.tpdo[TPDO_STATUS], 0x180 + nid, c.feedback_every, tpdo1_layout(fam),
                          rtr=False)
            self._map_pdo(node.tpdo[TPDO_MOTION], 0x280 + nid, c.feedback_every, tpdo2_layout(fam),
                          rtr=False)
        except Exception as exc:  # noqa: BLE001
            raise EposError(f"node {nid} ({d.cfg.name}): PDO mapping failed: {exc}") from exc
        # CiA 301 RxPDO event timer where a drive has it (maxon's EPOS4 EDS lists none): an
        # extra, nothing relies on it; with synchronous setpoints a hung master is stopped by
        # the drive's interpolation-period supervision (0x60C2: no RPDO in a cycle, EMCY 0x8250)
        if c.rpdo_timeout_ms:
            optional(0x1400, 5, c.rpdo_timeout_ms, "0x1400:05 RxPDO1 event timer (optional)", quiet=True)
        # 0x60C2 interpolation time period = the SYNC period: the drive then expects a setpoint
        # RPDO in every SYNC cycle (supervised: EMCY 0x8250). on_receipt is no cycle contract:
        # 0 (off), whatever an earlier master left there
        period_ms = c.sync_period * 1000.0 if c.synchronous else 0.0
        if abs(period_ms - round(period_ms)) < 1e-9 and 0 <= round(period_ms) <= 255:
            if optional(0x60C2, 1, int(round(period_ms)), "0x60C2:01 interpolation time period") is not None:
                optional(0x60C2, 2, -3, "0x60C2:02 interpolation time index")
        # our own fast decoders instead of canopen's per-variable ones
        net = self._connected_network()
        for cob in (0x180 + nid, 0x280 + nid, 0x200 + nid):
            if cob in net.subscribers:
                net.unsubscribe(cob)
        net.subscribe(0x180 + nid, self._make_tpdo1_cb(d))
        net.subscribe(0x280 + nid, self._make_tpdo2_cb(d))
        if self.echo:
            net.subscribe(0x200 + nid, self._make_echo_cb(d))
        d.target = State.SWITCH_ON_DISABLED
        d.controlword = 0
        d.setpoint = 0
        d.seen_operational = False           # a PRE-OP heartbeat may still be under way
        d.tpdo_seen = False
        node.nmt.send_command(0x01)          # NMT start -> OPERATIONAL
        d.operational = True
        d.last_heartbeat = self.clock()      # the heartbeat timeout counts from here
        d.pairing = SamplePairing(self.sync_watch.period_ns, c.feedback_every)
        self._publish(d, stamp=self.clock())

    def _apply_scaling(self, d: _Drive, sdo_read: Callable[..., int], sdo_write: Callable[..., None],
                       optional: Callable[..., Optional[int]]) -> None:
        """Motor data: read from the drive and checked against the config (``scaling_source``
        check), taken from the drive (drive, or ``read_motor_data``) or written to it (config);
        then the output current limit. EposError naming both values on disagreement."""
        nid, fam, u = d.node_id, d.units.family, d.units
        src = "drive" if d.cfg.read_motor_data else self.config.scaling_source
        who = f"node {nid} ({d.cfg.name})"
        if fam == "epos2":
            # EPOS2 setpoints are mA: no per-mille base to check
            if src == "drive":
                nom = sdo_read(0x6410, 1, "0x6410:01 continuous current limit (mA)")
                d.units = self._units_from_drive(d, nom, u.torque_constant_raw, u.counts_per_rev)
        else:
            if src == "config":
                sdo_write(0x3001, 1, u.nominal_current_ma, "0x3001:01 nominal current (mA)")
                sdo_write(0x3001, 5, u.torque_constant_raw, "0x3001:05 torque constant (µNm/A)")
                optional(0x6076, None, u.rated_torque_raw, "0x6076 motor rated torque (µNm)")
                optional(0x60A9, None, VELOCITY_UNIT_RPM, "0x60A9 SI unit velocity")
            nom = sdo_read(0x3001, 1, "0x3001:01 nominal current (mA)")
            kt = sdo_read(0x3001, 5, "0x3001:05 torque constant (µNm/A)")
            rated = optional(0x6076, None, None, "0x6076 motor rated torque (µNm)")
            res = optional(0x3000, 5, None, "0x3000:05 main sensor resolution (inc/rev)")
            vel = optional(0x60A9, None, None, "0x60A9 SI unit velocity")
            if vel is not None and vel != VELOCITY_UNIT_RPM:
                raise EposError(f"{who}: velocity unit 0x60A9 = 0x{vel:08X}, the bridge reads 0x606C "
                                f"in rpm (0x{VELOCITY_UNIT_RPM:08X}); set it on the drive or use "
                                "scaling_source: config")
            # the drive's per-mille base: I = ‰/1000 · 0x6076 / 0x3001:05
            base_ma = rated * 1000.0 / kt if rated and kt else float(nom)
            if src == "drive":
                d.units = self._units_from_drive(d, base_ma, kt, res or u.counts_per_rev)
            else:
                tol = self.config.scaling_tolerance
                checks = [("nominal current 0x3001:01", nom / 1000.0, u.nominal_current,
                           "units.nominal_current", "A"),
                          ("torque constant 0x3001:05", kt * 1e-6, u.torque_constant,
                           "units.torque_constant", "Nm/A"),
                          ("per-mille base 0x6076/0x3001:05", base_ma / 1000.0, u.nominal_current,
                           "units.nominal_current", "A")]
                if res:
                    checks.append(("encoder resolution 0x3000:05", float(res), u.counts_per_rev,
                                   "units.counts_per_rev", "inc/rev"))
                bad = [f"{what}: drive {dv:.6g} {unit}, config {key} {cv:.6g} {unit} "
                       f"({(dv - cv) / cv * 100.0:+.1f} %)"
                       for what, dv, cv, key, unit in checks if abs(dv - cv) > tol * abs(cv)]
                if bad:
                    raise EposError(f"{who}: motor data on the drive disagree with the config "
                                    f"(tolerance {tol * 100.0:g} %): " + "; ".join(bad)
                                    + "; fix the config or the drive, or set scaling_source: drive "
                                    "(use the drive's) or config (write the config's)")
        d.raw_limit = d.units.setpoint_limit(d.cfg.current_limit)
        if d.cfg.write_current_limit:
            lim_ma = int(math.floor(d.cfg.current_limit * 1000.0))
            if fam == "epos4":
                sdo_write(0x3001, 2, lim_ma, "0x3001:02 output current limit (mA)")
            else:
                sdo_write(0x6410, 2, lim_ma, "0x6410:02 output current limit (mA)")

    @staticmethod
    def _units_from_drive(d: _Drive, nominal_ma: float, kt: int, counts: float) -> DriveUnits:
        try:
            return DriveUnits.from_drive_objects(d.units.family, nominal_ma, kt, counts,  # type: ignore[arg-type]
                                                 d.units.gear_ratio, d.units.direction)
        except ValueError as exc:
            raise EposError(f"node {d.node_id}: motor data read from the drive is unusable: {exc}") from exc

    @staticmethod
    def _map_pdo(pdo_map: Any, cob_id: int, trans_type: int, layout: Sequence[tuple[int, int, str]],
                 rtr: bool = True) -> None:
        """Standard remap over SDO: disable (COB-ID bit 31), count 0, entries, count, enable;
        ``rtr`` False: COB-ID bit 30 set (CiA 301: no RTR allowed on this TPDO)."""
        pdo_map.clear()
        for index, sub, _ in layout:
            pdo_map.add_variable(index, sub)
        pdo_map.cob_id = cob_id
        pdo_map.rtr_allowed = rtr
        pdo_map.trans_type = trans_type
        pdo_map.enabled = True
        pdo_map.save()

    # --- master heartbeat, SYNC and monitoring ------------------------------------------------
    def _start_master_heartbeat(self) -> None:
        """Produce the master's heartbeat (OPERATIONAL) when ``master_heartbeat_ms`` > 0, from a
        thread of this process (never the kernel's periodic sender: a frozen master must fall
        silent, ``drive.heartbeat``)."""
        if self.config.master_heartbeat_ms and self._master_hb is None and self.network is not None:
            net, cob = self.network, 0x700 + self.config.master_node_id
            self._master_hb = HeartbeatSender(lambda: net.send_message(cob, b"\x05"),
                                              self.config.master_heartbeat_ms / 1000.0)

    def stop_master_heartbeat(self) -> None:
        """Stop producing the master's heartbeat (as a dead master would; SYNC keeps running)."""
        if self._master_hb is not None:
            try:
                self._master_hb.stop()
            finally:
                self._master_hb = None

    def start_sync(self) -> None:
        """Start the SYNC producer (``sync_period``) when this master produces SYNC
        (``sync_producer: master``); from now on SYNC must arrive (``sync_timeout``)."""
        if self.network is None:
            return
        if self.config.sync_producer == "master" and not self._sync_running:
            if type(self.network.bus).__name__ == "SocketcanBus":
                # the kernel's broadcast manager keeps the period whatever this process does
                self.network.sync.start(self.config.sync_period)
            else:
                # python-can's thread-based periodic sender would burst after a stall
                net = self.network
                self._sync_sender = SyncSender(lambda: net.send_message(SYNC_COB_ID, b""),
                                               self.config.sync_period)
            self._sync_running = True
        if self._sync_expected_since is None:
            self._sync_expected_since = self.clock()

    @property
    def sync_expected(self) -> bool:
        """SYNC runs on the bus (produced here or, ``external``, by another node)."""
        return self._sync_running or self._sync_expected_since is not None

    def set_receiver_priority(self, priority: int) -> bool:
        """SCHED_FIFO ``priority`` for the master's own threads: the canopen Network's bus
        receiver (it delivers SYNC and the echoes), the monitor (watchdogs, RPDO refresh) and a
        thread-based heartbeat sender. No thread of the master that takes the GIL is then
        preempted by ordinary processes while a FIFO thread (the player) waits for the GIL.
        False with a logged warning where not permitted."""
        net = self.network
        notifier = getattr(net, "notifier", None)
        threads = [t for t in getattr(notifier, "_readers", []) if isinstance(t, threading.Thread)]
        # this master's SYNC producer where it is a thread here (not the kernel's broadcast manager)
        for extra in (self._monitor, getattr(self._master_hb, "thread", None),
                      getattr(self._sync_sender, "thread", None)):
            if isinstance(extra, threading.Thread) and extra.is_alive():
                threads.append(extra)
        ok = bool(threads)
        for t in threads:
            ok = use_fifo(priority, f"master thread {t.name}", tid=t.native_id or 0) and ok
        return ok

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """A SYNC on the bus (receiver thread): its bus instant and the echoes before it."""
        echoes = tuple(d.echo_seq for d in self._drives) if self.echo else None
        ev = self.sync_watch.observe(timestamp, echoes)
        for d in self._drives:
            at = d.pairing.on_sync(ev.bus_ns) if d.pairing is not None else None
            if at is not None:           # a TPDO received before the SYNC it answers
                self._publish(d, sample_ns=at)

    def _on_cycle(self, ev: Any) -> None:
        """A SYNC seen (bus receiver's thread; ``ev`` a SyncEvent): the cycle it opens gets each
        operational drive's RPDO1 once: the value in force (controlword, setpoint) again when
        nothing went out since this SYNC. A player in another process does it for the enabled
        drives it feeds. A later new setpoint in the same cycle replaces it (the drive latches
        the last one before the SYNC)."""
        if self.network is None:
            return
        for d in self._drives:
            if not d.operational or d.cycle_sent >= ev.count:
                continue
            with self._send_lock:
                if d.operational and d.cycle_sent < ev.count and not self._player_owns(d):
                    d.cycle_repeats += 1
                    self._send_rpdo(d, d.controlword, d.setpoint)

    def _make_echo_cb(self, d: _Drive) -> Callable[[int, bytearray, float], None]:
        def on_echo(can_id: int, data: bytearray, timestamp: float) -> None:
            d.echo_seq += 1
            d.echo_log.append((d.echo_seq, int(round(timestamp * 1e9)) if timestamp else time.time_ns()))
        return on_echo

    def echo_time(self, marks: Sequence[int]) -> Optional[int]:
        """Bus instant (wall ns) by which the RPDOs numbered ``marks`` (``send_prepared``'s
        return, per joint) were all on the bus, from their echoes; None while one is missing."""
        latest = 0
        for d, m in zip(self._drives, marks):
            if m <= 0:
                continue
            log_ = list(d.echo_log)        # a copy: the receiver thread appends meanwhile
            i = m - log_[0][0] if log_ else -1     # echo numbers are consecutive
            if not 0 <= i < len(log_):
                return None
            latest = max(latest, log_[i][1])
        return latest

    def stop_sync(self) -> None:
        self._sync_expected_since = None
        if self.network is not None and self._sync_running:
            try:
                if self._sync_sender is not None:
                    self._sync_sender.stop()
                else:
                    self.network.sync.stop()
            finally:
                self._sync_sender = None
                self._sync_running = False

    def _start_monitor(self) -> None:
        if self._monitor is None or not self._monitor.is_alive():
            self._monitor_stop.clear()
            self._monitor = threading.Thread(target=self._monitor_loop, name="ff-epos-monitor",
                                             daemon=True)
            self._monitor.start()

    def _stop_monitor(self) -> None:
        self._monitor_stop.set()
        if self._monitor is not None:
            self._monitor.join(2.0)
            self._monitor = None

    def _monitor_loop(self) -> None:
        while not self._monitor_stop.wait(self.config.monitor_period):
            try:
                now = self.clock()
                self.check(now)
                for d in self._drives:
                    # on_receipt: keep the RPDO stream fed even when no TPDO arrives to step
                    # the state machine (sync: every SYNC cycle does, ``_on_cycle``)
                    if (not self.config.synchronous and d.operational and d.feedback.state is not None
                            and not self._player_owns(d) and now - d.last_tx >= REFRESH_PERIOD):
                        with self._send_lock:
                            self._send_rpdo(d, d.controlword, d.setpoint)
                    if d.history_wanted and d.operational:
                        d.history_wanted = False
                        self.read_error_history(d.cfg.name)
            except Exception:  # noqa: BLE001 - the monitor must keep running
                log.exception("monitor check failed")

    def read_error_history(self, joint: str) -> str:
        """Read a drive's error history (0x1003, newest first) and error code (0x603F) over SDO,
        decoded with maxon's error table; kept for the diagnostics and listed in ``events``."""
        d = next(x for x in self._drives if x.cfg.name == joint)
        try:
            with self._sdo_lock:
                n = int(d.node.sdo[0x1003][0].raw)
                codes = [int(d.node.sdo[0x1003][i].raw) for i in range(1, min(n, 8) + 1)]
                now_code = int(d.node.sdo[0x603F].raw)
        except Exception as exc:  # noqa: BLE001 - a report, never a reason to stop
            text = f"error history of node {d.node_id} not readable: {exc}"
        else:
            hist = ", ".join(str(describe(c)) for c in codes) or "empty"
            text = (f"node {d.node_id} ({d.cfg.name}) error code 0x603F: {describe(now_code)}; "
                    f"error history 0x1003: {hist}")
        d.error_history = text
        self.events.append((self.clock(), text))
        log.warning("%s", text)
        return text

    def check(self, now: float) -> Optional[str]:
        """Heartbeat / feedback timeouts and the setpoint watchdog at ``now``; returns a new
        fault reason if this call latched the safe state."""
        timeout = self.config.heartbeat_timeout
        reason = self._check_bus()
        if reason:
            return self.trip(reason)
        reason = self._check_sync(now)     # first: without SYNC the TPDOs stop too
        if reason:
            return self.trip(reason)
        for d in self._drives:
            if not d.operational:
                continue
            # until the first OPERATIONAL heartbeat / first TPDO after NMT start, allow
            # state_timeout (a drive may take a while to start its PDOs)
            grace = max(timeout, self.config.state_timeout)
            hb_limit = timeout if d.seen_operational else grace
            if d.last_heartbeat is not None and now - d.last_heartbeat > hb_limit:
                return self.trip(f"heartbeat lost: node {d.node_id} ({d.cfg.name}) silent for "
                                 f"{(now - d.last_heartbeat) * 1000.0:.0f} ms (timeout "
                                 f"{hb_limit * 1000.0:.0f} ms)")
            fb_limit = self.config.feedback_timeout if d.tpdo_seen else max(self.config.feedback_timeout, grace)
            if self.sync_expected and now - d.feedback.stamp > fb_limit:
                return self.trip(f"feedback lost: no TPDO from node {d.node_id} ({d.cfg.name}) for "
                                 f"{(now - d.feedback.stamp) * 1000.0:.0f} ms (timeout "
                                 f"{fb_limit * 1000.0:.0f} ms)")
            reason = self._envelope(d)
            if reason:
                return self.trip(reason)
        reason = self.guard.check(now, pending=self.pending_fn())
        if reason:
            self._react(reason)
            return reason
        return None

    def _check_bus(self) -> Optional[str]:
        """The bus itself failed: python-can's notifier stops its reader thread and keeps the
        exception (bus off, adapter unplugged, the simulation's hub gone). Said at once, instead
        of the heartbeat or SYNC loss that follows a timeout later. Once latched it is reported
        once; a configure (a new connection) is needed to run again."""
        notifier = getattr(self.network, "notifier", None)
        exc = getattr(notifier, "exception", None)
        if exc is None or self._bus_lost_told:
            return None
        self._bus_lost_told = True
        return f"CAN bus lost: {type(exc).__name__}: {exc} (configure again once the bus is back)"

    def _check_sync(self, now: float) -> Optional[str]:
        """SYNC loss: none for ``sync_timeout`` s (before the first: ``state_timeout`` as well)."""
        since = self._sync_expected_since
        if since is None or not any(d.operational for d in self._drives):
            return None
        limit = self.config.sync_timeout
        age = self.sync_watch.age_s()
        if age is None:
            age, limit = now - since, max(limit, self.config.state_timeout)
        else:
            age = min(age, now - since)
        if age <= limit:
            return None
        who = ("this master's SYNC producer" if self.config.sync_producer == "master"
               else "the external SYNC producer")
        return (f"SYNC lost: no SYNC (COB-ID 0x{SYNC_COB_ID:02X}) for {age * 1000.0:.0f} ms "
                f"(sync_timeout {limit * 1000.0:.0f} ms, {who}); the drives latch no setpoint")

    def _envelope(self, d: _Drive) -> Optional[str]:
        """The joint's position / velocity envelope (config), judged on the latest TPDOs."""
        cfg, fb = d.cfg, d.feedback
        if not d.tpdo_seen or (cfg.position_limits is None and cfg.velocity_limit is None):
            return None
        lo, hi = cfg.position_limits if cfg.position_limits is not None else (-math.inf, math.inf)
        vmax = cfg.velocity_limit if cfg.velocity_limit is not None else math.inf
        inside = lo <= fb.position <= hi and abs(fb.velocity) <= vmax
        if not d.envelope_armed:
            d.envelope_armed = inside       # re-armed once the joint is back inside
            return None
        if not lo <= fb.position <= hi:
            return (f"position envelope: {cfg.name} at {fb.position:.4f} rad, outside "
                    f"[{lo:g}, {hi:g}] rad")
        if abs(fb.velocity) > vmax:
            return (f"velocity envelope: {cfg.name} at {fb.velocity:.3f} rad/s, above "
                    f"{vmax:g} rad/s")
        return None

    # --- faults ---------------------------------------------------------------------------------
    def add_fault_listener(self, listener: Callable[[str], None]) -> None:
        """Call ``listener(reason)`` (on the thread that latched) once the safe state's
        zero-current reaction has been sent."""
        self._fault_listeners.append(listener)

    def remove_fault_listener(self, listener: Callable[[str], None]) -> None:
        """Stop calling ``listener`` (no error if it was not added)."""
        if listener in self._fault_listeners:
            self._fault_listeners.remove(listener)

    def trip(self, reason: str) -> Optional[str]:
        """Latch the safe state with ``reason`` (first reason wins) and react; returns it if new."""
        if self.guard.latch(reason):
            self._react(reason)
            return reason
        if not self.events or self.events[-1][1][:40] != f"also: {reason}"[:40]:
            self.events.append((self.clock(), f"also: {reason}"))
        return None

    def _react(self, reason: str) -> None:
        t_latch = self.clock()
        self.reset_epoch_ns = max(self.reset_epoch_ns, time.time_ns())
        for d in self._drives:
            state = d.feedback.state
            d.target = State.QUICK_STOP_ACTIVE if state is State.OPERATION_ENABLED else State.SWITCH_ON_DISABLED
        self._gate_changed()              # an external player stops sending before the reaction
        log.error("safe state: %s", reason)
        for d in self._drives:
            state = d.feedback.state
            if d.operational:
                cw = (cia402.CONTROLWORD[cia402.Command.QUICK_STOP]
                      if d.target is State.QUICK_STOP_ACTIVE
                      else cia402.CONTROLWORD[cia402.Command.DISABLE_VOLTAGE])
                self._send_rpdo(d, cw, 0)
                if self.config.synchronous and not self._sync_fresh():
                    # a synchronous RPDO takes effect at the next SYNC only: with SYNC gone the
                    # controlword goes as an SDO write too (applied on receipt)
                    self._send_sdo_controlword(d, cw)
        # stamped at the latch, listed once the zero-current reaction has been sent: whoever
        # sees the event also sees applied_currents() == 0
        self.events.append((t_latch, f"safe state: {reason}"))
        for listener in list(self._fault_listeners):
            try:
                listener(reason)
            except Exception:  # noqa: BLE001 - one failing listener must not stop the others
                log.exception("fault listener failed")

    def _make_emcy_cb(self, d: _Drive) -> Callable[[Any], None]:
        def on_emcy(err: Any) -> None:
            code = int(err.code)
            if code & 0xFF00 == 0:
                d.emcy.append(f"0x{code:04X} error reset")
                return
            info = describe(code)
            text = (f"EMCY from node {d.node_id} ({d.cfg.name}): code 0x{code:04X} {info.text} "
                    f"({'warning' if info.warning else 'error'}), error register "
                    f"0x{int(err.register):02X}")
            if info.warning:            # the drive keeps operating: report, do not latch
                d.warnings.append(text)
                self.events.append((self.clock(), text))
                log.warning("%s", text)
                return
            d.emcy.append(text)
            d.history_wanted = True
            self.trip(text)
        return on_emcy

    def _make_heartbeat_cb(self, d: _Drive) -> Callable[[int, bytearray, float], None]:
        def on_heartbeat(can_id: int, data: bytearray, timestamp: float) -> None:
            if not data:
                return
            now = self.clock()
            code = data[0] & 0x7F
            d.nmt_state = NMT_STATES.get(code, f"0x{code:02X}")
            if code == 0x00:
                d.boot_count += 1
                d.last_boot = now
                if d.operational:
                    d.operational = False
                    self.trip(f"node {d.node_id} ({d.cfg.name}) rebooted (boot-up frame) while "
                              "in operation; configure again")
                return
            d.last_heartbeat = now
            if code == 0x05:
                d.seen_operational = True
            elif d.operational and d.seen_operational and code in (0x04, 0x7F):
                d.operational = False
                self.trip(f"node {d.node_id} ({d.cfg.name}) left OPERATIONAL (heartbeat reports "
                          f"{d.nmt_state}); configure again")
        return on_heartbeat

    # --- feedback and the state machine --------------------------------------------------------
    def _make_tpdo1_cb(self, d: _Drive) -> Callable[[int, bytearray, float], None]:
        fmt = d.tx1_fmt
        size = struct.calcsize(fmt)

        def on_tpdo1(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) < size:
                return
            sw, pos = struct.unpack_from(fmt, data)
            try:
                state: Optional[State] = cia402.decode_statusword(sw)
            except cia402.StatuswordError:
                state = None
            now = self.clock()
            tpdo_ns = int(round(timestamp * 1e9)) if timestamp else time.time_ns()
            sample_ns = self._sample_instant(d, tpdo_ns, proxy)
            before = d.feedback.state
            fb = self._publish(d, statusword=sw, position_raw=pos, position=d.units.increments_to_rad(pos),
                               state=state, stamp=now, sample_ns=sample_ns)
            if state is not before and self.external_player:
                self._gate_changed()
            d.tpdo_seen = True
            if sw & SW_INTERNAL_LIMIT and self.guard.motion_running:
                if not d.limited_count:
                    d.limited_first_ns = fb.sample_ns
                d.limited_count += 1
            if proxy:
                # no echo of our own SYNC: the first drive's synchronous TPDO1 marks the cycle
                self.sync_watch.observe(timestamp, None)
            self._step(d, now)
        proxy = (d is self._drives[0] and self.config.sync_producer == "master" and not self.echo)
        return on_tpdo1

    @staticmethod
    def _object_dictionary(d: _Drive) -> Any:
        """The master's object dictionary of a drive: built in, or read from the joint's EDS/DCF
        (canopen.import_od) and checked to hold every object and sub-index the master uses."""
        built = build_object_dictionary(d.units.family, d.node_id)
        if d.cfg.eds is None:
            return built
        try:
            od = canopen.import_od(d.cfg.eds, d.node_id)
        except Exception as exc:  # noqa: BLE001 - any parse error is the file's
            raise EposError(f"node {d.node_id} ({d.cfg.name}): cannot read the EDS {d.cfg.eds!r}: {exc}") from exc
        missing = []
        for obj in built.values():
            if obj.index not in od:
                missing.append(f"0x{obj.index:04X}")
                continue
            subs = getattr(obj, "subindices", None)
            if subs:
                have = od[obj.index]
                missing += [f"0x{obj.index:04X}:{k:02X}" for k in subs
                            if k not in getattr(have, "subindices", {}) and (obj.index, k) not in OPTIONAL_SUBS]
        if missing:
            raise EposError(f"node {d.node_id} ({d.cfg.name}): the EDS {d.cfg.eds!r} lacks object(s) the "
                            f"master uses: {', '.join(missing[:12])}" + (" ..." if len(missing) > 12 else ""))
        return od

    def _sample_instant(self, d: _Drive, tpdo_ns: int, proxy: bool) -> int:
        """Wall ns at which a synchronous TPDO's values were sampled: the SYNC it answers when
        the pairing is certain (``SamplePairing``), else its own bus instant."""
        if proxy or d.pairing is None or (self.config.sync_producer == "master" and not self.echo):
            return tpdo_ns              # our own SYNC is not seen on this bus: no better instant
        return d.pairing.on_tpdo(tpdo_ns)

    def _make_tpdo2_cb(self, d: _Drive) -> Callable[[int, bytearray, float], None]:
        fmt = d.tx2_fmt
        size = struct.calcsize(fmt)

        def on_tpdo2(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) < size:
                return
            rpm, cur = struct.unpack_from(fmt, data)
            self._publish(d, velocity_raw=rpm, current_raw=cur, velocity=d.units.rpm_to_rad_s(rpm),
                          current=d.units.ma_to_amps(cur), stamp_motion=self.clock())
        return on_tpdo2

    def _step(self, d: _Drive, now: float) -> None:
        """One non-blocking state-machine step after a fresh statusword."""
        state = d.feedback.state
        if state is None or not d.operational:
            return
        if state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
            if now >= d.reset_until and not self.guard.latched:
                d.history_wanted = True
                self.trip(f"drive fault: node {d.node_id} ({d.cfg.name}) is in '{state.value}' "
                          f"(statusword 0x{d.feedback.statusword:04X})"
                          + (f"; last {d.emcy[-1]}" if d.emcy else ""))
            if now >= d.reset_until:
                return           # stay in Fault until an explicit fault reset
        with self._send_lock:     # decide and send atomically w.r.t. command_currents
            target = d.target
            if target is State.QUICK_STOP_ACTIVE and state not in (State.OPERATION_ENABLED,
                                                                   State.QUICK_STOP_ACTIVE):
                target = State.SWITCH_ON_DISABLED
            try:
                cw, _ = cia402.next_controlword(state, target, d.controlword)
            except cia402.TransitionError:
                cw = cia402.HOLD_CONTROLWORD.get(state, 0)
            setpoint = d.setpoint if (state is State.OPERATION_ENABLED
                                      and target is State.OPERATION_ENABLED
                                      and not self.guard.latched) else 0
            # RPDOs are not acknowledged: sync, every SYNC cycle repeats them (``_on_cycle``);
            # on_receipt, while the drive is not where we want it, repeat the controlword (a
            # lost quick stop must not leave the drive driving current), and refresh the RPDO
            # now and then anyway (a lost setpoint heals)
            since = now - d.last_tx
            if self._player_owns(d) and cw == d.controlword:
                return                    # the player's RPDOs (one per cycle) carry it
            repeat = not self.config.synchronous and ((state is not target and since >= RESEND_PERIOD)
                                                      or since >= REFRESH_PERIOD)
            if cw != d.controlword or setpoint != d.setpoint or repeat:
                self._send_rpdo(d, cw, setpoint)

    def gate(self) -> list[tuple[int, bool]]:
        """Per joint: (controlword, True when a current may be sent: operational, in and meant
        for Operation enabled, no safe state latched)."""
        latched = self.guard.latched
        return [(d.controlword, bool(not latched and d.operational
                                     and d.feedback.state is State.OPERATION_ENABLED
                                     and d.target is State.OPERATION_ENABLED))
                for d in self._drives]

    def _gate_changed(self) -> None:
        fn = self.gate_listener
        if fn is not None:
            try:
                fn()
            except Exception:  # noqa: BLE001 - the caller is the state machine / a reaction
                log.exception("gate listener failed")

    def _player_owns(self, d: _Drive) -> bool:
        """An external player feeds this enabled drive's RPDO (no refresh from here)."""
        return (self.external_player and not self.guard.latched
                and d.feedback.state is State.OPERATION_ENABLED
                and d.target is State.OPERATION_ENABLED)

    def _sync_fresh(self) -> bool:
        """A SYNC came within the last three periods (the reaction's RPDO will be latched)."""
        age = self.sync_watch.age_s() if self.sync_watch is not None else None
        return age is not None and age < 3.0 * float(self.config.sync_period)

    def _send_sdo_controlword(self, d: _Drive, controlword: int) -> None:
        """Write 0x6040 with one expedited SDO download frame (CiA 301: command 0x2B, 2 bytes),
        without waiting for the answer: the safe state must not block on a drive or bus that
        does not answer (canopen's SDO client drops the stray answer before its next request)."""
        data = struct.pack("<BHBH2x", 0x2B, 0x6040, 0, int(controlword) & 0xFFFF)
        with self._send_lock:
            try:
                self._connected_network().send_message(0x600 + d.node_id, data)
            except Exception:  # noqa: BLE001 - a full bus must not kill the caller's thread
                self.tx_errors += 1
                log.exception("SDO controlword to node %d failed", d.node_id)

    def _send_rpdo(self, d: _Drive, controlword: int, setpoint: int) -> None:
        """Send RPDO1 (controlword + raw setpoint, clamped to the raw limit)."""
        sp = max(-d.raw_limit, min(d.raw_limit, int(setpoint)))
        if self.guard.latched or self.external_player:
            sp = 0
        data = struct.pack(d.rx_fmt, int(controlword) & 0xFFFF, sp)
        with self._send_lock:
            changed = d.controlword != int(controlword) & 0xFFFF
            d.controlword = int(controlword) & 0xFFFF
            d.setpoint = sp
            d.last_tx = self.clock()
            d.cycle_sent = self.sync_watch.count
            if changed and self.external_player:
                self._gate_changed()      # the player learns the new controlword first
            try:
                self._connected_network().send_message(0x200 + d.node_id, data)
                d.tx_seq += 1
            except Exception:  # noqa: BLE001 - a full bus must not kill the caller's thread
                self.tx_errors += 1
                d.tx_failing += 1
                if d.tx_failing == 1:    # a lost bus fails every cycle: one traceback, then a count
                    log.exception("RPDO to node %d failed (the next failures are counted, not "
                                  "logged, until one goes through)", d.node_id)
                return
            if d.tx_failing:
                log.warning("RPDO to node %d goes through again after %d failed", d.node_id,
                            d.tx_failing)
                d.tx_failing = 0

    # --- requests --------------------------------------------------------------------------------
    def _set_target(self, target: State) -> None:
        now = self.clock()
        for d in self._drives:
            d.target = target
        if self.external_player:
            self._gate_changed()
        for d in self._drives:
            if d.feedback.state is not None:
                self._step(d, now)

    def enable(self) -> None:
        """Request Operation enabled (zero current); refused (EposError) while latched."""
        if self.guard.latched:
            raise EposError(f"safe state latched ({self.guard.reason}); call fault_reset() first")
        for d in self._drives:
            d.setpoint = 0
        self._set_target(State.OPERATION_ENABLED)

    def disable(self) -> None:
        """Zero current, then request Switched on (disable operation, transition 5)."""
        self.command_zero()
        self._set_target(State.SWITCHED_ON)

    def disable_voltage(self) -> None:
        """Zero current, request Switch on disabled."""
        self.command_zero()
        self._set_target(State.SWITCH_ON_DISABLED)

    def quick_stop(self, reason: str = "quick stop requested") -> None:
        """Latch the safe state: zero current and quick stop."""
        self.trip(reason)

    def estop(self, reason: str = "requested") -> str:
        """Emergency stop: latch the safe state (zero current, quick stop) with ``reason``;
        returns the reason in force (an earlier latch keeps its own)."""
        self.trip(f"e-stop: {reason}")
        return self.guard.reason or f"e-stop: {reason}"

    def fault_reset(self, reenable: bool = True) -> Optional[str]:
        """Clear the latch and reset drive faults (controlword bit 7 rising edge, transition 15);
        then request Operation enabled (``reenable``) or Switch on disabled. Returns the cleared
        reason. The current stays 0 until a setpoint stamped after this call."""
        now = self.clock()
        self.reset_epoch_ns = max(self.reset_epoch_ns, time.time_ns())
        for d in self._drives:
            d.reset_until = now + self.config.state_timeout
            d.setpoint = 0
            d.envelope_armed = False     # armed again once back inside the envelope
            if d.operational and d.feedback.state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
                # make sure the reset bit rises even if it was left set
                self._send_rpdo(d, 0x0000, 0)
            d.last_heartbeat = now if d.operational else d.last_heartbeat
            self._publish(d, stamp=now, state=None)    # wait for a fresh statusword before judging
        old = self.guard.reset()
        for d in self._drives:
            if not d.operational and self.network is not None and self._configured:
                # the node rebooted: set it up again (blocking SDO), or latch again
                try:
                    self._configure_drive(d)
                    d.reset_until = self.clock() + self.config.state_timeout
                except EposError as exc:
                    self.trip(f"fault reset: {exc}")
                    return old
        self.events.append((now, f"fault reset (cleared: {old})"))
        self._set_target(State.OPERATION_ENABLED if reenable else State.SWITCH_ON_DISABLED)
        return old

    def wait_for_state(self, state: State, timeout: Optional[float] = None) -> bool:
        """Block until every drive reports ``state`` (polling); False on timeout or a latch."""
        deadline = self.clock() + (self.config.state_timeout if timeout is None else timeout)
        while self.clock() < deadline:
            if all(d.feedback.state is state for d in self._drives):
                return True
            if self.guard.latched and state is State.OPERATION_ENABLED:
                return False
            time.sleep(0.002)
        return all(d.feedback.state is state for d in self._drives)

    # --- commands -------------------------------------------------------------------------------
    def prepare_currents(self, amps: Sequence[float]) -> PreparedCommand:
        """Guard + unit conversion of motor currents (A, one per joint), nothing sent yet: lets a
        player do the work before a stamp and only ``send_prepared`` at it."""
        cmd = self.guard.filter(amps)
        raws = tuple(d.units.amps_to_setpoint(float(a), limit=d.cfg.current_limit)
                     for d, a in zip(self._drives, cmd.currents))
        return PreparedCommand(cmd, raws)

    def send_prepared(self, prepared: PreparedCommand) -> tuple[int, ...]:
        """Send prepared setpoints (one RPDO per joint). Zero while latched or when a drive is
        not (to be) in Operation enabled; the raw value is clamped to the limit once more.
        Returns per joint the RPDO count including these (``rpdo_marks`` right after each)."""
        marks = []
        for d, raw in zip(self._drives, prepared.raw):
            with self._send_lock:
                if (self.guard.latched or d.feedback.state is not State.OPERATION_ENABLED
                        or d.target is not State.OPERATION_ENABLED):
                    raw = 0
                if d.operational:
                    self._send_rpdo(d, d.controlword, raw)
                marks.append(d.tx_seq)
        return tuple(marks)

    def command_currents(self, amps: Sequence[float]) -> SafeCommand:
        """Send motor currents (A, one per joint) through the guard now; returns what was sent."""
        prepared = self.prepare_currents(amps)
        self.send_prepared(prepared)
        return prepared.command

    def command_zero(self) -> None:
        """Zero current on every joint (no latch)."""
        for d in self._drives:
            if d.operational:
                self._send_rpdo(d, d.controlword, 0)
            d.setpoint = 0

    def note_setpoint(self, motion_running: bool) -> None:
        """Feed the setpoint watchdog (a fresh setpoint arrived); a motion that starts here
        clears the per-motion record of statusword bit 11 (``motion_limits``)."""
        starts = motion_running and not self.guard.motion_running
        self.guard.feed(self.clock(), motion_running)
        if starts:
            for d in self._drives:
                d.limited_count, d.limited_first_ns = 0, 0

    def motion_limits(self) -> list[tuple[int, int]]:
        """Per joint, during the latest motion (from its first setpoint until it ended): how many
        feedback TPDOs had statusword bit 11 set (internal limit active: the drive clipped the
        command, so the move did not get the planned current) and the wall ns of the first
        (0: none)."""
        return [(d.limited_count, d.limited_first_ns) for d in self._drives]

    def rpdo_marks(self) -> tuple[int, ...]:
        """Per joint, how many setpoint RPDOs have been handed to the bus (compare with the
        echo counts of a :class:`~ff_hwbridge.drive.sync_watch.SyncEvent`)."""
        return tuple(d.tx_seq for d in self._drives)

    def applied_currents(self) -> np.ndarray:
        """A, the currents last sent (from the raw setpoints)."""
        return np.array([d.units.setpoint_to_amps(d.setpoint) for d in self._drives])

"""Maxon EPOS4 / EPOS2 CANopen master on the ``canopen`` library (no rclpy).

One :class:`EposMaster` drives a group of joints (one EPOS each) on one python-can bus. It is
composed by concern, as ros2_canopen splits its CiA 402 driver:

- ``drive.boot``          ``configure()``: per drive NMT reset communication + boot-up, SDO set-up,
                          PDO mapping, NMT start (:class:`~ff_hwbridge.drive.boot.Boot`);
- ``drive.state_machine`` ``enable()`` / ``disable()`` / ``quick_stop()`` set a *target* CiA 402
                          state, reached one controlword step per received statusword;
- ``drive.tpdo``          the feedback TPDOs as immutable snapshots, each placed at its SYNC;
- ``drive.watchdogs``     heartbeat / TPDO / SYNC / bus loss, the envelope, the setpoint watchdog,
                          EMCY, and the safe state (zero current, quick stop, reason kept until
                          ``fault_reset()``, which sets up a rebooted node again);
- ``drive.rpdo``          RPDO1 in every SYNC cycle (the value in force repeated), guard + units of
                          the commands (``command_currents``, ``prepare_currents`` / ``send_prepared``);
- this module             the connection (``connect()`` / ``disconnect()``, which disables every
                          drive at a SYNC before the per-cycle RPDO stops and disarms 0x1016), the
                          SYNC producer (the kernel's broadcast manager on SocketCAN, else
                          ``drive.sync_sender``), the master's heartbeat (a thread here,
                          ``drive.heartbeat``), ``fault_reset()`` and the diagnostics.

Command line: ``ff-epos`` (``ff_hwbridge.cli.epos``).
"""
from __future__ import annotations

import logging
import threading
import time
from collections import deque
from typing import Any, Callable, Optional

import canopen

from ff_hwbridge.drive.boot import Boot
from ff_hwbridge.drive.bus import open_bus
from ff_hwbridge.drive.config import BridgeConfig
from ff_hwbridge.drive.feedback import JointFeedback
from ff_hwbridge.drive.heartbeat import HeartbeatSender
from ff_hwbridge.drive.node import (ECHO_INTERFACES, REFRESH_PERIOD, RESEND_PERIOD, SYNC_COB_ID, EposError,
                                    PreparedCommand, _Drive)
from ff_hwbridge.drive.realtime import use_fifo
from ff_hwbridge.drive.rpdo import RpdoWriter
from ff_hwbridge.drive.safety import SafetyGuard
from ff_hwbridge.drive.state_machine import StateMachine
from ff_hwbridge.drive.sync_sender import SyncSender
from ff_hwbridge.drive.sync_watch import SyncWatch
from ff_hwbridge.drive.tpdo import FeedbackReceiver
from ff_hwbridge.drive.watchdogs import Watchdogs
from ff_hwbridge.protocol import cia402
from ff_hwbridge.protocol.cia402 import SW_INTERNAL_LIMIT, SW_WARNING, State
from ff_hwbridge.protocol.epos_errors import EMCY_CLASSES
from ff_hwbridge.protocol.epos_od import struct_format, rpdo_layout, tpdo1_layout, tpdo2_layout
from ff_hwbridge.protocol.units import DriveUnits

log = logging.getLogger(__name__)

__all__ = ["ECHO_INTERFACES", "EMCY_CLASSES", "REFRESH_PERIOD", "RESEND_PERIOD", "SYNC_COB_ID", "EposError",
           "EposMaster", "JointFeedback", "PreparedCommand"]


class EposMaster(StateMachine, RpdoWriter, FeedbackReceiver, Watchdogs, Boot):
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
        # the setpoint RPDOs, and the cycle contract: every SYNC seen, each operational drive
        # this master owns gets its RPDO once
        self.rpdos = self._make_rpdos()
        self.sync_watch.add_listener(self._on_cycle)

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

    def status(self) -> dict[str, Any]:
        """A flat summary for diagnostics."""
        now = self.clock()
        out: dict[str, Any] = {"safe_state": self.guard.latched,
                               "reason": self.guard.reason or "",
                               "configured": self._configured, "tx_errors": self.tx_errors}
        for d in self._drives:
            p = f"{d.cfg.name}."
            out[p + "node_id"] = d.node_id
            fb = d.feedback               # one snapshot: state and statusword of the same TPDO
            out[p + "state"] = fb.state.value if fb.state else "unknown"
            out[p + "target"] = d.target.value
            out[p + "statusword"] = f"0x{fb.statusword:04X}"
            out[p + "nmt"] = d.nmt_state or "unknown"
            out[p + "heartbeat_age_ms"] = (round((now - d.last_heartbeat) * 1000.0, 1)
                                           if d.last_heartbeat is not None else -1.0)
            out[p + "setpoint_raw"] = d.rpdo.setpoint
            out[p + "cycle_repeats"] = d.rpdo.repeats     # RPDOs repeating the value in force
            out[p + "last_emcy"] = d.emcy[-1] if d.emcy else ""
            sw = fb.statusword
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
            d.rpdo.fmt = struct_format(rpdo_layout(d.units.family))
            d.tx1_fmt = struct_format(tpdo1_layout(d.units.family))
            d.tx2_fmt = struct_format(tpdo2_layout(d.units.family))
            d.rpdo.raw_limit = d.units.setpoint_limit(d.cfg.current_limit)
            net.subscribe(0x700 + d.node_id, self._make_heartbeat_cb(d))
            node.emcy.add_callback(self._make_emcy_cb(d))
        net.subscribe(SYNC_COB_ID, self._on_sync)

    def disconnect(self) -> None:
        """Zero current, disable voltage at a SYNC (``disable_at_sync``), disarm the drives'
        consumer of this master's heartbeat (0x1016:01 = 0: a clean exit is no heartbeat loss,
        and the next start finds the drive out of Fault), stop SYNC and the monitor, close the
        bus (idempotent)."""
        self._stop_monitor()
        if self.network is None:
            return
        try:
            self.disable_at_sync()
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

    def disable_at_sync(self, timeout: Optional[float] = None) -> bool:
        """Zero current and disable voltage on every drive, and keep SYNC and the per-cycle RPDO
        going until a SYNC has latched it: at least two SYNCs after the send, and every drive
        reporting a state other than Operation enabled (or ``timeout`` s, default
        ``state_timeout``). A drive in a cyclic synchronous mode whose RPDOs stop while it is
        still enabled faults (EMCY 0x8250, interpolation aborted). True when every drive left
        Operation enabled in time (or SYNC is not expected)."""
        count = self.sync_watch.count
        for d in self._drives:
            d.target = State.SWITCH_ON_DISABLED
            if d.operational:
                self._send_rpdo(d, cia402.CONTROLWORD[cia402.Command.DISABLE_VOLTAGE], 0)
        if not (self.config.synchronous and self.sync_expected) or self._bus_lost_told:
            return True
        deadline = self.clock() + (self.config.state_timeout if timeout is None else timeout)
        while True:
            enabled = [d.cfg.name for d in self._drives
                       if d.operational and d.feedback.state is State.OPERATION_ENABLED]
            if self.sync_watch.count >= count + 2 and not enabled:
                return True
            if self.clock() >= deadline:
                log.warning("disable: %s still in Operation enabled after %d SYNC(s)",
                            ", ".join(enabled) or "no drive", self.sync_watch.count - count)
                return not enabled
            time.sleep(0.002)

    def _connected_network(self) -> canopen.Network:
        """The canopen Network; EposError before ``connect()`` / after ``disconnect()``."""
        if self.network is None:
            raise EposError("the CAN network is not connected; call connect() first")
        return self.network

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

    def fault_reset(self, reenable: bool = True) -> Optional[str]:
        """Clear the latch and reset drive faults (controlword bit 7 rising edge, transition 15);
        then request Operation enabled (``reenable``) or Switch on disabled. Returns the cleared
        reason. The current stays 0 until a setpoint stamped after this call."""
        now = self.clock()
        self.reset_epoch_ns = max(self.reset_epoch_ns, time.time_ns())
        for d in self._drives:
            d.reset_until = now + self.config.state_timeout
            d.rpdo.setpoint = 0
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

    def note_setpoint(self, motion_running: bool) -> None:
        """Feed the setpoint watchdog (a fresh setpoint arrived); a motion that starts here
        clears the per-motion record of statusword bit 11 (``motion_limits``)."""
        starts = motion_running and not self.guard.motion_running
        self.guard.feed(self.clock(), motion_running)
        if starts:
            for d in self._drives:
                d.limited_count, d.limited_first_ns, d.limited_armed = 0, 0, True

    def motion_limits(self) -> list[tuple[int, int]]:
        """Per joint, since the latest motion's first setpoint (through its applied end): how many
        feedback TPDOs had statusword bit 11 set (internal limit active: the drive clipped the
        command, so the move did not get the planned current) and the wall ns of the first
        (0: none)."""
        return [(d.limited_count, d.limited_first_ns) for d in self._drives]

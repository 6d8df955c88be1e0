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
- RPDOs are not acknowledged: while a drive's state differs from its target the controlword is
                  repeated every 5 ms, and every RPDO is refreshed at least every 50 ms.
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
from ff_hwbridge.drive.safety import SafeCommand, SafetyGuard
from ff_hwbridge.protocol import cia402
from ff_hwbridge.protocol.cia402 import State
from ff_hwbridge.protocol.epos_od import (RPDO_SETPOINT, TPDO_MOTION, TPDO_STATUS, build_object_dictionary,
                                          rpdo_layout, struct_format, tpdo1_layout, tpdo2_layout)
from ff_hwbridge.protocol.units import DriveUnits

log = logging.getLogger(__name__)

NMT_STATES = {0x00: "BOOTUP", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE-OPERATIONAL"}
# A few CiA 301/402 / maxon emergency code classes, for readable reasons.
EMCY_CLASSES = {0x00: "error reset / no error", 0x10: "generic error", 0x20: "current",
                0x23: "current, device output side", 0x30: "voltage", 0x32: "voltage inside device",
                0x40: "temperature", 0x42: "device temperature", 0x50: "device hardware",
                0x60: "device software", 0x70: "additional modules", 0x73: "sensor",
                0x80: "monitoring / communication", 0x81: "communication", 0x82: "protocol error",
                0x84: "velocity/following", 0x86: "position", 0x90: "external error",
                0xF0: "additional functions", 0xFF: "device specific"}


# s: repeat the controlword while the drive's state differs from the target; refresh any RPDO
# at least this often (both are idempotent for the drive: a fault reset needs a rising edge)
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
class JointFeedback:
    """Latest measured values of one joint (rad, rad/s, A) and its drive state."""

    position: float = 0.0
    velocity: float = 0.0
    current: float = 0.0
    statusword: int = 0
    state: Optional[State] = None
    position_raw: int = 0
    velocity_raw: int = 0
    current_raw: int = 0
    stamp: float = 0.0            # monotonic s of the latest TPDO1
    stamp_motion: float = 0.0     # monotonic s of the latest TPDO2


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
    emcy: deque = field(default_factory=lambda: deque(maxlen=20))   # recent EMCY texts

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
        self._drives = [_Drive(cfg=j, units=j.units) for j in config.joints]
        self._send_lock = threading.RLock()
        self._monitor: Optional[threading.Thread] = None
        self._monitor_stop = threading.Event()
        self._sync_running = False
        self._master_hb: Any = None
        self._configured = False
        self.events: deque[tuple[float, str]] = deque(maxlen=200)   # (monotonic s, text)
        self.tx_errors = 0

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
        """A copy of the latest feedback per joint."""
        return [replace(d.feedback) for d in self._drives]

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
            out[p + "last_emcy"] = d.emcy[-1] if d.emcy else ""
        return out

    # --- connection -----------------------------------------------------------------------------
    def connect(self, bus: Any = None) -> None:
        """Open the bus (or use ``bus``, a python-can bus) and add one RemoteNode per joint."""
        if self.network is not None:
            return
        if bus is None:
            bus = open_bus(self.config.bus.as_dict())   # checks loopback-only remotes
        net = canopen.Network(bus)
        net.NOTIFIER_CYCLE = 0.1        # bounds how long disconnect() waits for the receiver
        net.connect()
        self.network = net
        for d in self._drives:
            od = build_object_dictionary(d.units.family, d.node_id)
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

    def disconnect(self) -> None:
        """Zero current, disable voltage, stop SYNC and the monitor, close the bus (idempotent)."""
        self._stop_monitor()
        if self.network is None:
            return
        try:
            for d in self._drives:
                d.target = State.SWITCH_ON_DISABLED
                if d.operational:
                    self._send_rpdo(d, cia402.CONTROLWORD[cia402.Command.DISABLE_VOLTAGE], 0)
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
        self._configured = True

    def _configure_drive(self, d: _Drive) -> None:
        node, nid, fam = d.node, d.node_id, d.units.family
        d.operational = False
        d.last_heartbeat = None
        if self.config.reset_communication:
            t0 = self.clock()
            boots = d.boot_count
            node.nmt.send_command(0x82)     # reset communication
            deadline = t0 + self.config.boot_timeout
            while d.boot_count == boots and self.clock() < deadline:
                time.sleep(0.002)
            if d.boot_count == boots:
                raise EposError(f"node {nid} ({d.cfg.name}): no boot-up frame within "
                                f"{self.config.boot_timeout} s after NMT reset communication; "
                                "check the node id, bitrate, wiring / the drive is powered")

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
        if self.config.master_heartbeat_ms:
            consumer = (self.config.master_node_id << 16) | (3 * self.config.master_heartbeat_ms)
            sdo_write(0x1016, 1, consumer, "0x1016:01 consumer heartbeat time (master)")
        if d.cfg.read_motor_data:
            if fam == "epos4":
                nom = sdo_read(0x3001, 1, "0x3001:01 nominal current (mA)")
                kt = sdo_read(0x3001, 5, "0x3001:05 torque constant (µNm/A)")
            else:
                nom = sdo_read(0x6410, 1, "0x6410:01 continuous current limit (mA)")
                kt = d.units.torque_constant_raw
            try:
                d.units = DriveUnits.from_drive_objects(fam, nom, kt, d.units.counts_per_rev,
                                                        d.units.gear_ratio, d.units.direction)
            except ValueError as exc:
                raise EposError(f"node {nid}: motor data read from the drive is unusable: {exc}") from exc
            d.raw_limit = d.units.setpoint_limit(d.cfg.current_limit)
        if d.cfg.write_current_limit:
            lim_ma = int(math.floor(d.cfg.current_limit * 1000.0))
            if fam == "epos4":
                sdo_write(0x3001, 2, lim_ma, "0x3001:02 output current limit (mA)")
            else:
                sdo_write(0x6410, 2, lim_ma, "0x6410:02 output current limit (mA)")
        try:
            self._map_pdo(node.rpdo[RPDO_SETPOINT], 0x200 + nid, 255, rpdo_layout(fam))
            self._map_pdo(node.tpdo[TPDO_STATUS], 0x180 + nid, 1, tpdo1_layout(fam))
            self._map_pdo(node.tpdo[TPDO_MOTION], 0x280 + nid, 1, tpdo2_layout(fam))
        except Exception as exc:  # noqa: BLE001
            raise EposError(f"node {nid} ({d.cfg.name}): PDO mapping failed: {exc}") from exc
        # our own fast decoders instead of canopen's per-variable ones
        net = self._connected_network()
        for cob in (0x180 + nid, 0x280 + nid, 0x200 + nid):
            if cob in net.subscribers:
                net.unsubscribe(cob)
        net.subscribe(0x180 + nid, self._make_tpdo1_cb(d))
        net.subscribe(0x280 + nid, self._make_tpdo2_cb(d))
        d.target = State.SWITCH_ON_DISABLED
        d.controlword = 0
        d.setpoint = 0
        d.seen_operational = False           # a PRE-OP heartbeat may still be under way
        d.tpdo_seen = False
        node.nmt.send_command(0x01)          # NMT start -> OPERATIONAL
        d.operational = True
        d.last_heartbeat = self.clock()      # the heartbeat timeout counts from here
        d.feedback.stamp = self.clock()

    @staticmethod
    def _map_pdo(pdo_map: Any, cob_id: int, trans_type: int, layout: Sequence[tuple[int, int, str]]) -> None:
        """Standard remap over SDO: disable (COB-ID bit 31), count 0, entries, count, enable."""
        pdo_map.clear()
        for index, sub, _ in layout:
            pdo_map.add_variable(index, sub)
        pdo_map.cob_id = cob_id
        pdo_map.trans_type = trans_type
        pdo_map.enabled = True
        pdo_map.save()

    # --- master heartbeat, SYNC and monitoring ------------------------------------------------
    def _start_master_heartbeat(self) -> None:
        """Produce the master's heartbeat (OPERATIONAL) when ``master_heartbeat_ms`` > 0."""
        if self.config.master_heartbeat_ms and self._master_hb is None and self.network is not None:
            self._master_hb = self.network.send_periodic(
                0x700 + self.config.master_node_id, bytes([0x05]),
                self.config.master_heartbeat_ms / 1000.0)

    def stop_master_heartbeat(self) -> None:
        """Stop producing the master's heartbeat (as a dead master would; SYNC keeps running)."""
        if self._master_hb is not None:
            try:
                self._master_hb.stop()
            finally:
                self._master_hb = None

    def start_sync(self) -> None:
        """Start the SYNC producer (``sync_period``)."""
        if self.network is not None and not self._sync_running:
            self.network.sync.start(self.config.sync_period)
            self._sync_running = True

    def stop_sync(self) -> None:
        if self.network is not None and self._sync_running:
            try:
                self.network.sync.stop()
            finally:
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
                self.check(self.clock())
            except Exception:  # noqa: BLE001 - the monitor must keep running
                log.exception("monitor check failed")

    def check(self, now: float) -> Optional[str]:
        """Heartbeat / feedback timeouts and the setpoint watchdog at ``now``; returns a new
        fault reason if this call latched the safe state."""
        timeout = self.config.heartbeat_timeout
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
            if self._sync_running and now - d.feedback.stamp > fb_limit:
                return self.trip(f"feedback lost: no TPDO from node {d.node_id} ({d.cfg.name}) for "
                                 f"{(now - d.feedback.stamp) * 1000.0:.0f} ms (timeout "
                                 f"{fb_limit * 1000.0:.0f} ms)")
        reason = self.guard.check(now, pending=self.pending_fn())
        if reason:
            self._react(reason)
            return reason
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
        log.error("safe state: %s", reason)
        t_latch = self.clock()
        for d in self._drives:
            state = d.feedback.state
            d.target = State.QUICK_STOP_ACTIVE if state is State.OPERATION_ENABLED else State.SWITCH_ON_DISABLED
            if d.operational:
                cw = (cia402.CONTROLWORD[cia402.Command.QUICK_STOP]
                      if d.target is State.QUICK_STOP_ACTIVE
                      else cia402.CONTROLWORD[cia402.Command.DISABLE_VOLTAGE])
                self._send_rpdo(d, cw, 0)
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
            cls = EMCY_CLASSES.get(code >> 8, EMCY_CLASSES.get((code >> 12) << 4, "error"))
            text = (f"EMCY from node {d.node_id} ({d.cfg.name}): code 0x{code:04X} ({cls}), "
                    f"error register 0x{int(err.register):02X}")
            d.emcy.append(text)
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
            fb = d.feedback
            fb.statusword, fb.position_raw = sw, pos
            fb.position = d.units.increments_to_rad(pos)
            try:
                fb.state = cia402.decode_statusword(sw)
            except cia402.StatuswordError:
                fb.state = None
            now = self.clock()
            fb.stamp = now
            d.tpdo_seen = True
            self._step(d, now)
        return on_tpdo1

    def _make_tpdo2_cb(self, d: _Drive) -> Callable[[int, bytearray, float], None]:
        fmt = d.tx2_fmt
        size = struct.calcsize(fmt)

        def on_tpdo2(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) < size:
                return
            rpm, cur = struct.unpack_from(fmt, data)
            fb = d.feedback
            fb.velocity_raw, fb.current_raw = rpm, cur
            fb.velocity = d.units.rpm_to_rad_s(rpm)
            fb.current = d.units.ma_to_amps(cur)
            fb.stamp_motion = self.clock()
        return on_tpdo2

    def _step(self, d: _Drive, now: float) -> None:
        """One non-blocking state-machine step after a fresh statusword."""
        state = d.feedback.state
        if state is None or not d.operational:
            return
        if state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
            if now >= d.reset_until and not self.guard.latched:
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
            # RPDOs are not acknowledged: while the drive is not where we want it, repeat the
            # controlword (a lost quick stop must not leave the drive driving current), and
            # refresh the RPDO now and then anyway (a lost setpoint heals)
            since = now - d.last_tx
            if (cw != d.controlword or setpoint != d.setpoint
                    or (state is not target and since >= RESEND_PERIOD)
                    or since >= REFRESH_PERIOD):
                self._send_rpdo(d, cw, setpoint)

    def _send_rpdo(self, d: _Drive, controlword: int, setpoint: int) -> None:
        """Send RPDO1 (controlword + raw setpoint, clamped to the raw limit)."""
        sp = max(-d.raw_limit, min(d.raw_limit, int(setpoint)))
        if self.guard.latched:
            sp = 0
        data = struct.pack(d.rx_fmt, int(controlword) & 0xFFFF, sp)
        with self._send_lock:
            d.controlword = int(controlword) & 0xFFFF
            d.setpoint = sp
            d.last_tx = self.clock()
            try:
                self._connected_network().send_message(0x200 + d.node_id, data)
            except Exception:  # noqa: BLE001 - a full bus must not kill the caller's thread
                self.tx_errors += 1
                log.exception("RPDO to node %d failed", d.node_id)

    # --- requests --------------------------------------------------------------------------------
    def _set_target(self, target: State) -> None:
        now = self.clock()
        for d in self._drives:
            d.target = target
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

    def fault_reset(self, reenable: bool = True) -> Optional[str]:
        """Clear the latch and reset drive faults (controlword bit 7 rising edge, transition 15);
        then request Operation enabled (``reenable``) or Switch on disabled. Returns the cleared
        reason."""
        now = self.clock()
        for d in self._drives:
            d.reset_until = now + self.config.state_timeout
            d.setpoint = 0
            if d.operational and d.feedback.state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
                # make sure the reset bit rises even if it was left set
                self._send_rpdo(d, 0x0000, 0)
            d.last_heartbeat = now if d.operational else d.last_heartbeat
            d.feedback.stamp = now
            d.feedback.state = None          # wait for a fresh statusword before judging
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

    def send_prepared(self, prepared: PreparedCommand) -> None:
        """Send prepared setpoints (one RPDO per joint). Zero while latched or when a drive is
        not (to be) in Operation enabled; the raw value is clamped to the limit once more."""
        for d, raw in zip(self._drives, prepared.raw):
            with self._send_lock:
                if (self.guard.latched or d.feedback.state is not State.OPERATION_ENABLED
                        or d.target is not State.OPERATION_ENABLED):
                    raw = 0
                if d.operational:
                    self._send_rpdo(d, d.controlword, raw)

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
        """Feed the setpoint watchdog (a fresh setpoint arrived)."""
        self.guard.feed(self.clock(), motion_running)

    def applied_currents(self) -> np.ndarray:
        """A, the currents last sent (from the raw setpoints)."""
        return np.array([d.units.setpoint_to_amps(d.setpoint) for d in self._drives])

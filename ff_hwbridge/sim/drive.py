"""An emulated Maxon EPOS4 / EPOS2 as a CANopen slave (canopen LocalNode + an OD built in code).

What it does, per the suite's CANopen contract (CiA 301/402):

- boot-up frame (0x700+id, data 0x00) on ``boot()`` and after NMT reset node / reset
  communication, then PRE-OPERATIONAL; NMT start / stop / pre-operational.
- SDO server for the objects below; PDO communication/mapping objects written over SDO in the
  standard way (COB-ID bit 31 set, count 0, entries, count, COB-ID re-enabled) are validated and
  the PDO maps RELOADED at once.
- RPDOs applied the moment they arrive (transmission type 254/255); synchronous RPDOs (types
  0-240) are latched at the next SYNC, as an EPOS4 in a cyclic mode does. Timing model: every
  frame carries its BUS timestamp (the instant the hub, or python-can's virtual channel, put it
  on the bus; wall clock). A synchronous RPDO takes effect at the BUS instant of the first SYNC
  whose bus timestamp is later than its own (an RPDO on the bus after a SYNC waits for the next
  one; one stamped before a SYNC but delivered after it, which a virtual channel allows, is
  latched by that SYNC, in the past), converted to ``time.monotonic_ns`` for the plant, and not
  when this process got around to reading the SYNC frame; the arm plant runs behind the frames (its own clock), so the
  current steps at that exact past instant. TPDOs are sampled at the SYNC's bus instant too.
  What is not modelled: the drive's own latching delay after SYNC (EPOS4: within its current
  loop, tens of µs, a constant) and current-loop dynamics; the setpoint is a current step.
  The controlword drives the CiA 402 state machine (the tables of ``cia402``, plus the
  EPOS's "switch on & enable operation" 0x000F from READY TO SWITCH ON = transitions 3+4, and
  the quick stop option code 0x605A: 0 = disable at once, 1-4 = stop, then SWITCH ON DISABLED
  once the motor stands still, 5-8 = stop and stay in QUICK STOP ACTIVE), the setpoint becomes
  motor current, clamped to the drive's own output current limit like a real drive. Current is
  only driven in OPERATION ENABLED and in the drive's current mode (EPOS4 CST 10, EPOS2 -3).
- Stop ramps: a quick stop (0x605A 1/2/5/6, 3/4/7/8 at the current limit) or a fault reaction
  (0x605E 1/2; 0 = current 0 at once) of a moving motor brakes it under the drive's velocity
  loop, the speed reference falling at 0x6085 quick stop deceleration (or 0x6084 profile
  deceleration for the slow down ramp; rpm/s of the motor), to standstill; a fault waits in
  FAULT REACTION ACTIVE meanwhile. 0x6085 is a velocity deceleration, so the ramp is a speed
  ramp, not a torque ramp. The loop is tuned to ``DriveConfig.load_inertia`` (0: no ramp).
  On a plant that takes a current law (``SimArm.set_law``) the loop runs in the plant's time
  every 0.4 ms, as in the drive's firmware, whatever this process's threads do: a starved
  thread neither holds a braking current past standstill (driving the arm back the other way)
  nor ends a ramp early; the drive's 2 ms thread only ends the ramp once the arm stands still.
- TPDOs with transmission type 1-240 sent on every n-th SYNC in OPERATIONAL, sampled at the SYNC's
  arrival; event-driven TPDOs (254/255, maxon's default for TxPDO1) on a change of a mapped
  value, no sooner than the inhibit time, and every event timer if set;
  heartbeat producer per 0x1017; EMCY (0x080+id) with error register 0x1001 and the
  pre-defined error field 0x1003 on a fault; fault reset by a rising controlword bit 7
  (EMCY "error reset" 0x0000 sent).
- Heartbeat consumer 0x1016:01-04 ((node id << 16) | ms): once a consumed heartbeat has been
  seen, silence longer than its time is a communication error (EMCY 0x8130 heartbeat error), so
  a dead master stops the drive as on the real EPOS. The reaction to a communication error is
  0x6007 abort connection option (0 none but the EMCY, 1 fault, 2 disable voltage, 3 quick
  stop; maxon default 3), then the NMT state per 0x1029:01 (0 pre-operational, 1 unchanged,
  2 stopped). This watchdog runs on the drive's own thread. There is no RxPDO event timer
  (maxon's EPOS4 EDS has no 0x1400+n:05: SDO abort 0x06090011, as for every object the EDS lacks).
- Interpolation supervision (EPOS4, CSP/CSV/CST with 0x60C2 interpolation time period set, in
  OPERATION ENABLED): every SYNC interval must bring a new target RPDO, or the drive faults
  with EMCY 0x8250 "RPDO timeout" (maxon: interpolation aborted in cyclic mode, no PDO within
  the interpolation time period), current 0 per 0x605E. So a master that hangs, whatever keeps
  its SYNC and heartbeat going, stops the drive within a few periods. Judged on the frames' bus
  instants at each SYNC, ``SUPERVISION_SLACK_NS`` of SYNCs after the interval (an RPDO on the
  bus before a SYNC may be handled after it); ``DriveConfig.interpolation_supervision`` /
  ``SimEpos.interpolation_supervision`` = False turns it off (tests of old masters only).
- Warnings (``raise_warning``, e.g. 0xFF01): EMCY sent, statusword bit 7 set, no state change.
  Statusword bit 11 (internal limit active) while the setpoint is clamped to the current limit.
  0x603F error code = the code of the present fault; 0x1003 the history, newest first.
- Every received setpoint is recorded with its arrival time (``time.monotonic_ns`` and wall clock
  ``time.time_ns``), so benchmarks can compare the time a setpoint was due with when it applied.
- Fault injection: stop heartbeat, raise EMCY, stop answering SDO, delay / drop frames, power
  off (hears and sends nothing until ``boot``), bus lost (``bus_lost``: Fault 0x81FD CAN bus off,
  current 0; ``reattach`` puts it on a new bus, PRE-OPERATIONAL, EMCY sent then).
- Every state change is stamped by the drive (``state_log``, ``left_enabled_ns``,
  ``zero_current_ns``: ``time.monotonic_ns``), for timing faults at the drive itself.
- Factory settings as maxon's: 0x605A 6, 0x605E 2, 0x6007 3, 0x1029:01 0 (the objects and
  defaults of ``ff_hwbridge/sim/epos4.eds``).

Units on the wire (maxon EPOS4 Firmware Specification / object dictionary; the search tool here
did not return maxon's own pages, so these are from maxon's EDS/firmware conventions as recalled,
cross-checked with CiA 402 where it defines them):
  0x6071 target torque, 0x6077 torque actual: INT16, per mille (‰) of 0x6076.
  0x6076 motor rated torque: UNSIGNED32, µNm (0.001 mNm); EPOS4 derives it as
         0x3001:01 nominal current × 0x3001:05 torque constant.
  0x3001:01 nominal current, :02 output current limit: UNSIGNED32, mA.
  0x3001:05 torque constant: UNSIGNED32, µNm/A (0.001 mNm/A).
  Hence I [A] = ‰/1000 · 0x6076 / 0x3001:05 = ‰/1000 · I_nominal.
  0x30D1:01/:02 current actual averaged / actual: INT32, mA (EPOS4); 0x6078 INT16 mA (EPOS2).
  0x2030 current mode setting value: INT16, mA (EPOS2); 0x6410:01/:02 UNSIGNED16 mA (EPOS2).
  0x6064 position actual: INT32, encoder increments of the motor shaft; 0x606C velocity actual:
  INT32, motor rpm (EPOS4 default SI unit of velocity).
NMT STOPPED halts PDOs and SDO but (as on the real drive) does not change the power stage.
"""
from __future__ import annotations

import bisect
import functools
import heapq
import math
import random
import struct
import threading
import time
from collections import deque
from dataclasses import dataclass
from importlib import resources
from typing import Any, Callable, Optional, cast

import canopen
from canopen import objectdictionary as od
from canopen.objectdictionary import ObjectDictionary, ODVariable
from canopen.pdo.base import PdoBase, PdoMaps
from canopen.sdo import SdoAbortedError

from ff_hwbridge.drive.realtime import StallDump
from ff_hwbridge.protocol import cia402, epos_od
from ff_hwbridge.protocol.cia402 import Command, State
from ff_hwbridge.protocol.epos_od import (CURRENT_MODE, FACTORY_QUICK_STOP_OPTION, MAXON_VENDOR_ID,  # noqa: F401
                                          PDO_VALID_BIT, MotorData)
from ff_hwbridge.protocol.units import FAMILIES, DriveUnits
from ff_hwbridge.sim.sync import wall_minus_mono

_NUMBER_TYPES = od.NUMBER_TYPES
VALID_MODES = {"epos4": {0, 1, 3, 6, 8, 9, 10}, "epos2": {0, -3, -2, -1, 1, 3, 6, 7}}
# the contract's setpoint (RPDO1 entry 2) and actual current (TPDO2 entry 2) objects per family
SETPOINT_OBJ = {f: epos_od.rpdo_layout(f)[1][:2] for f in FAMILIES}
CURRENT_OBJ = {f: epos_od.tpdo2_layout(f)[1][:2] for f in FAMILIES}

# SDO abort codes (CiA 301)
ABORT_NOT_MAPPABLE = 0x06040041
ABORT_PDO_TOO_LONG = 0x06040042
ABORT_VALUE_RANGE = 0x06090030
ABORT_DEVICE_STATE = 0x08000022
ABORT_NOT_IN_OD = 0x06020000
ABORT_NO_SUBINDEX = 0x06090011

#: The EPOS4 EDS of the simulated drive (CiA 306; maxon's indices, data types and defaults)
EPOS4_EDS = "epos4.eds"


@functools.lru_cache(maxsize=None)
def eds_objects() -> dict[tuple[int, int], int]:
    """(index, sub-index) -> CANopen data type of every object of ``ff_hwbridge/sim/epos4.eds``,
    read with canopen's EDS import: what a simulated EPOS4 may serve."""
    with resources.as_file(resources.files("ff_hwbridge.sim") / EPOS4_EDS) as path:
        eds = canopen.import_od(str(path), 1)
    out: dict[tuple[int, int], int] = {}
    for obj in eds.values():
        for var in [obj] if isinstance(obj, ODVariable) else obj.values():
            if var.data_type is None:
                raise SimConfigError(f"{EPOS4_EDS}: 0x{var.index:04X}:{var.subindex:02X} has no DataType")
            out[(var.index, var.subindex)] = int(var.data_type)
    return out


class SimConfigError(ValueError):
    """A simulated-drive setting that cannot be used; the message says what to change."""


@dataclass(frozen=True)
class DriveConfig:
    """One emulated drive: identity, motor data and encoder (motor side; A, Nm/A, counts)."""

    node_id: int = 1
    family: str = "epos4"               # 'epos4' (CST, 0x6071 ‰) or 'epos2' (current mode, 0x2030 mA)
    nominal_current: float = 3.0        # A, 0x3001:01 / 0x6410:01
    current_limit: float = 10.0         # A, output current limit 0x3001:02 / 0x6410:02
    torque_constant: float = 0.0267     # Nm/A, 0x3001:05
    counts_per_rev: int = 2048          # encoder increments per motor revolution (quadcounts)
    gear_ratio: float = 54.0            # joint angle = motor angle / gear_ratio
    quick_stop_option: int = FACTORY_QUICK_STOP_OPTION   # 0x605A at power-on (maxon: 6)
    load_inertia: float = 0.0           # kg m² at the joint, the velocity loop's tuning for stop
                                        # ramps (0 = unknown: quick stop / fault reaction cut the
                                        # current at once)
    interpolation_supervision: bool = True   # CSx: a SYNC interval without a new target -> 0x8250
                                             # (an EPOS4's rule; off only for tests of old masters)

    def __post_init__(self) -> None:
        if not 1 <= int(self.node_id) <= 127:
            raise SimConfigError(f"node_id must be 1..127, got {self.node_id}")
        if self.family not in FAMILIES:
            raise SimConfigError(f"family must be one of {FAMILIES}, got {self.family!r}")
        for k in ("nominal_current", "current_limit", "torque_constant", "gear_ratio"):
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise SimConfigError(f"{k} must be a finite number > 0, got {v!r}")
        if not (isinstance(self.load_inertia, (int, float)) and math.isfinite(self.load_inertia)
                and self.load_inertia >= 0):
            raise SimConfigError(f"load_inertia must be a finite number >= 0 kg m², got {self.load_inertia!r}")
        if int(self.counts_per_rev) <= 0:
            raise SimConfigError(f"counts_per_rev must be > 0, got {self.counts_per_rev}")
        lim_ma = 65535 if self.family == "epos2" else 2**32 - 1
        if self.current_limit * 1000 > lim_ma or self.nominal_current * 1000 > lim_ma:
            raise SimConfigError(f"currents above {lim_ma} mA do not fit the {self.family} objects")

    def units(self) -> DriveUnits:
        """The drive's motor and encoder data as the suite's unit conversions."""
        return DriveUnits(self.family, self.nominal_current, self.torque_constant,
                          self.counts_per_rev, self.gear_ratio)


@dataclass(frozen=True)
class SetpointRecord:
    """One applied setpoint: when (monotonic ns, wall ns: the arrival, or for a synchronous RPDO
    the bus instant of the SYNC that latched it), raw value, current (A)."""

    mono_ns: int
    wall_ns: int
    raw: int
    commanded: float      # A, after unit conversion, before clamping
    applied: float        # A, what the power stage drives (0 unless OPERATION ENABLED + mode)
    source: str           # 'rpdo' or 'sdo'


@dataclass(frozen=True)
class StateChange:
    """One CiA 402 state change of the drive, stamped by the drive itself (monotonic ns, wall ns)
    at the instant it took effect."""

    mono_ns: int
    wall_ns: int
    state: State
    transition: int


@dataclass
class FaultSettings:
    """Injected faults; change through SimEpos methods (thread-safe enough: plain attributes)."""

    heartbeat_stopped: bool = False
    unpowered: bool = False          # switched off: hears and sends nothing
    sdo_silent: bool = False
    rx_delay_s: float = 0.0
    tx_delay_s: float = 0.0
    rx_drop_fraction: float = 0.0
    tx_drop_fraction: float = 0.0
    rx_drop_next: int = 0
    tx_drop_next: int = 0


@dataclass
class LinkStats:
    rx_frames: int = 0
    rx_dropped: int = 0
    tx_frames: int = 0
    tx_dropped: int = 0
    rx_lag_max_us: float = 0.0      # longest a frame waited between its bus time and its handling
    rx_late: int = 0                # frames handled more than RX_LATE_S after their bus time
    handle_max_us: float = 0.0      # longest the drive took to handle one frame


#: s: a frame handled this long after its bus time counts as late (``LinkStats.rx_late``)
RX_LATE_S = 0.1
#: s, ``SimEpos.stall_dump``'s default: with > 0, no SYNC handled for this long after one was
#: (a stalled drive process, or SYNC stopped) dumps every thread's stack to stderr
#: (``faulthandler``: its watchdog needs no GIL, so it sees what holds it); 0 = off
STALL_DUMP_S = 0.0
#: EPOS4 cyclic synchronous modes (0x6060) -> their target object: CSP 0x607A, CSV 0x60FF, CST 0x6071
CSX_TARGETS = {8: 0x607A, 9: 0x60FF, 10: 0x6071}
#: EMCY code of the interpolation supervision (maxon: "RPDO timeout", interpolation aborted in
#: cyclic mode: no PDO within the interpolation time period)
RPDO_TIMEOUT = 0x8250
#: ns: a SYNC interval is judged once the drive has seen SYNCs for this long after it (at least
#: one), so that an RPDO on the bus inside it but handled after a later SYNC still counts
SUPERVISION_SLACK_NS = 30_000_000
#: SYNCs a drive remembers, with what each latched, to latch an RPDO delivered late at the SYNC
#: it was on the bus before (at 1 kHz: 0.25 s; an older one is latched at the oldest remembered)
SYNC_HISTORY = 256


@dataclass
class _SyncLatch:
    """One SYNC a drive handled: its bus instant (wall ns), the plant's clock then (monotonic ns)
    and, per RPDO map (``id``), the bus stamp (wall ns) and data of the RPDO it latched."""

    bus: int
    t_ns: int
    latched: dict[int, tuple[int, bytes]]


_POWERED = frozenset({State.OPERATION_ENABLED})
_BRAKING = frozenset({State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE})
#: s, time constant of the drive's velocity loop while it brakes on a ramp
RAMP_TAU = 0.02
#: rad/s at the joint: below this the motor counts as standing still
STANDSTILL = 0.002
RPM_S = 2.0 * math.pi / 60.0      # rad/s² per rpm/s


@dataclass
class _Ramp:
    """A stop on a deceleration ramp (quick stop 0x6085, slow down 0x6084, or at the current
    limit): the speed reference falls from ``v0`` (rad/s, joint) to 0 at ``alpha`` rad/s²."""

    kind: str               # 'quick_stop' or 'fault'
    t0_ns: int
    v0: float
    alpha: float            # rad/s² at the joint (inf: at the current limit)
    t_max: float            # s, the ramp is cut (current 0) after this
SW_FOLLOWS_COMMAND = 1 << 12   # cyclic synchronous / current mode: drive follows the setpoint


def drive_step(state: State, controlword: int, previous: int,
               quick_stop_option: int) -> tuple[State, list[int]]:
    """What the drive does with one controlword: (new state, transition numbers fired)."""
    cmd = cia402.decode_controlword(controlword, previous)
    if cmd is None:
        return state, []
    if cmd is Command.FAULT_RESET:
        return (State.SWITCH_ON_DISABLED, [15]) if state is State.FAULT else (state, [])
    if state is State.READY_TO_SWITCH_ON and cmd is Command.ENABLE_OPERATION:
        return State.OPERATION_ENABLED, [3, 4]
    if state is State.OPERATION_ENABLED and cmd is Command.QUICK_STOP and quick_stop_option == 0:
        return State.SWITCH_ON_DISABLED, [9]
    t = cia402.apply_command(state, cmd, allow_quick_stop_recovery=5 <= quick_stop_option <= 8)
    return (t.target, [t.number]) if t is not None else (state, [])


def _maps(pdo: PdoBase) -> PdoMaps:
    """The PDO maps of a node's RPDO / TPDO object (canopen creates them with the node)."""
    if pdo.map is None:
        raise SimConfigError("the node has no PDO maps")
    return pdo.map


class NullPlant:
    """A motor on no arm: holds the commanded current, never moves (for protocol-only tests)."""

    def __init__(self) -> None:
        self.current = 0.0

    def set_current(self, current: float, t_ns: int) -> None:
        self.current = current

    def sample(self, t_ns: int) -> tuple[float, float, float]:
        return 0.0, 0.0, self.current


# ------------------------------------------------------------------------------------------------
# Object dictionary
# ------------------------------------------------------------------------------------------------
def build_object_dictionary(cfg: DriveConfig) -> ObjectDictionary:
    """The drive's object dictionary: ``epos_od.OBJECTS`` with the drive-only objects, motor data
    from ``cfg`` (mA, µNm/A, µNm = nominal current x kt)."""
    motor = MotorData.from_units(cfg.units(), int(round(cfg.current_limit * 1000)))
    return epos_od.build_object_dictionary(cfg.family, cfg.node_id, motor=motor, drive=True,
                                           quick_stop_option=cfg.quick_stop_option,
                                           device_name=f"{cfg.family.upper()} (simulated)")


# ------------------------------------------------------------------------------------------------
# The link between one drive and the canopen Network: fault injection + arrival stamps
# ------------------------------------------------------------------------------------------------
class _DelayLine:
    """Runs callables at given monotonic instants on one thread, in due order (FIFO on ties)."""

    def __init__(self, name: str) -> None:
        self._heap: list[tuple[int, int, Callable[[], None]]] = []
        self._seq = 0
        self._cv = threading.Condition()
        self._stop = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def put(self, due_ns: int, fn: Callable[[], None]) -> None:
        with self._cv:
            self._seq += 1
            heapq.heappush(self._heap, (due_ns, self._seq, fn))
            self._cv.notify()

    def _run(self) -> None:
        while True:
            with self._cv:
                while not self._stop and (not self._heap or self._heap[0][0] > time.monotonic_ns()):
                    wait = None if not self._heap else (self._heap[0][0] - time.monotonic_ns()) * 1e-9
                    self._cv.wait(wait if wait is None else max(wait, 0.0))
                if self._stop:
                    return
                _, _, fn = heapq.heappop(self._heap)
            try:
                fn()
            except Exception:  # a delayed frame must not kill the line
                pass

    def close(self) -> None:
        with self._cv:
            self._stop = True
            self._cv.notify()
        self._thread.join(timeout=2.0)


class _PeriodicSender:
    """canopen-compatible periodic task (stop/update) that sends through the drive's link.

    Replaces canopen's use of the bus's cyclic sender, so heartbeats obey fault injection (and
    python-can-remote's broken ``modify_data`` is never involved)."""

    def __init__(self, link: "_Link", can_id: int, data: bytes, period: float) -> None:
        self._link, self._id, self._data, self._period = link, can_id, bytes(data), period
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"periodic-{can_id:03X}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        nxt = time.monotonic()
        while not self._stop.is_set():
            if not (self._id & 0x780 == 0x700 and self._link.faults.heartbeat_stopped):
                try:
                    self._link.send_message(self._id, self._data)
                except Exception:
                    pass
            nxt += self._period
            now = time.monotonic()
            if nxt < now:               # held off the CPU: skip the missed beats, no burst
                nxt = now + self._period
            self._stop.wait(max(0.0, nxt - now))

    def update(self, data: Any) -> None:
        self._data = bytes(data)

    def stop(self) -> None:
        self._stop.set()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout=2.0)


class _Link:
    """What one drive's LocalNode sees as its network: the real canopen Network plus faults.

    Incoming frames are stamped (monotonic and wall ns) before they are dispatched, then dropped,
    delayed or passed on; outgoing frames likewise."""

    def __init__(self, network: canopen.Network, faults: FaultSettings, node_id: int,
                 seed: Optional[int] = None, stall_dump: float = STALL_DUMP_S) -> None:
        self.network, self.faults, self.node_id = network, faults, node_id
        self.stats = LinkStats()
        self.rx_by_id: dict[int, int] = {}        # frames seen per COB-ID (diagnostics)
        self.rx_mono_ns = 0
        self.rx_wall_ns = 0
        self.rx_bus_ns = 0            # the frame's bus timestamp (wall ns; arrival if none)
        self.rx_lag_ns = 0            # how long after its bus timestamp the frame was handled
        self._wrappers: dict[tuple[int, Any], Callable] = {}
        self._rng = random.Random(seed)
        self._dispatch = threading.RLock()
        self._delay: Optional[_DelayLine] = None
        self._send_lock = threading.Lock()
        # re-armed at most every 0.5 s: faulthandler restarts its watchdog thread on each re-arm,
        # measured 17 ms a call in the 2-DOF driver at load ~14 (10 a second: 17 % of its time)
        self.stall = StallDump(stall_dump, rearm_every=0.5)

    def _delay_line(self) -> _DelayLine:
        if self._delay is None:
            self._delay = _DelayLine(f"epos{self.node_id}-delay")
        return self._delay

    def _drop(self, direction: str) -> bool:
        f = self.faults
        nxt = f"{direction}_drop_next"
        if getattr(f, nxt) > 0:
            setattr(f, nxt, getattr(f, nxt) - 1)
            return True
        frac = getattr(f, f"{direction}_drop_fraction")
        return frac > 0.0 and self._rng.random() < frac

    # canopen Network interface used by LocalNode / NmtSlave / PdoMap / EmcyProducer / SdoServer
    def subscribe(self, can_id: int, callback: Callable) -> None:
        key = (can_id, callback)
        if key in self._wrappers:
            return

        def wrapper(cid: int, data: bytearray, timestamp: float, _cb=callback) -> None:
            mono, wall = time.monotonic_ns(), time.time_ns()
            self.stats.rx_frames += 1
            self.rx_by_id[cid] = self.rx_by_id.get(cid, 0) + 1
            f = self.faults
            if f.unpowered or (f.sdo_silent and cid == 0x600 + self.node_id):
                return
            if self._drop("rx"):
                self.stats.rx_dropped += 1
                return
            frame = bytes(data)
            if f.rx_delay_s > 0.0:
                due = mono + int(f.rx_delay_s * 1e9)
                self._delay_line().put(due, lambda: self._deliver(_cb, cid, frame, timestamp, None))
                return
            self._deliver(_cb, cid, frame, timestamp, (mono, wall))

        self._wrappers[key] = wrapper
        self.network.subscribe(can_id, wrapper)

    def _deliver(self, cb: Callable, cid: int, data: bytes, timestamp: float,
                 stamps: Optional[tuple[int, int]]) -> None:
        with self._dispatch:
            if stamps is None:
                stamps = (time.monotonic_ns(), time.time_ns())
            self.rx_mono_ns, self.rx_wall_ns = stamps
            self.rx_bus_ns = int(round(timestamp * 1e9)) if timestamp else stamps[1]
            began = time.time_ns()
            self.rx_lag_ns = began - self.rx_bus_ns
            lag = self.rx_lag_ns / 1e3
            st = self.stats
            if lag > st.rx_lag_max_us:
                st.rx_lag_max_us = lag
            if lag > RX_LATE_S * 1e6:
                st.rx_late += 1
            if cid == 0x80:
                self.stall.arm(stamps[0])
            cb(cid, bytearray(data), timestamp)
            took = (time.time_ns() - began) / 1e3
            if took > st.handle_max_us:
                st.handle_max_us = took

    def unsubscribe(self, can_id: int, callback: Optional[Callable] = None) -> None:
        for key in [k for k in self._wrappers if k[0] == can_id and callback in (None, k[1])]:
            w = self._wrappers.pop(key)
            try:
                self.network.unsubscribe(can_id, w)
            except (KeyError, ValueError):
                pass

    def unsubscribe_all(self) -> None:
        for cid, cb in list(self._wrappers):
            self.unsubscribe(cid, cb)

    def send_message(self, can_id: int, data: Any, remote: bool = False) -> None:
        data = bytes(data)
        if self.faults.unpowered:
            return
        if self._drop("tx"):
            self.stats.tx_dropped += 1
            return
        if self.faults.tx_delay_s > 0.0:
            due = time.monotonic_ns() + int(self.faults.tx_delay_s * 1e9)
            self._delay_line().put(due, lambda: self._send_now(can_id, data, remote))
            return
        self._send_now(can_id, data, remote)

    def _send_now(self, can_id: int, data: bytes, remote: bool) -> None:
        self.stats.tx_frames += 1
        self.network.send_message(can_id, data, remote)

    def send_periodic(self, can_id: int, data: Any, period: float, remote: bool = False) -> _PeriodicSender:
        return _PeriodicSender(self, can_id, bytes(data or b""), period)

    def close(self) -> None:
        self.unsubscribe_all()
        self.stall.disarm()
        if self._delay is not None:
            self._delay.close()
            self._delay = None


# ------------------------------------------------------------------------------------------------
# The drive
# ------------------------------------------------------------------------------------------------
class _DriveNode(canopen.LocalNode):
    """LocalNode that tells its drive after every stored write (so PDO maps can be reloaded)."""

    def __init__(self, drive: "SimEpos", node_id: int, dictionary: ObjectDictionary) -> None:
        self._drive = drive
        super().__init__(node_id, dictionary)

    def set_data(self, index: int, subindex: int, data: bytes, check_writable: bool = False) -> None:
        super().set_data(index, subindex, data, check_writable)
        self._drive._after_write(index, subindex)


class SimEpos:
    """One emulated EPOS drive attached to a canopen Network, pushing current into a plant.

    ``plant`` is anything with ``set_current(A, t_ns)`` and ``sample(t_ns) -> (q rad, qd rad/s,
    I A)`` at the JOINT (``sim_arm.JointPort``); default a motor on no arm (``NullPlant``).
    """

    def __init__(self, config: DriveConfig, plant: Any = None, *, seed: Optional[int] = None,
                 log_capacity: int = 200_000) -> None:
        self.config = config
        self.family = config.family
        self.plant = plant if plant is not None else NullPlant()
        self.faults = FaultSettings()
        self._seed = seed
        self._lock = threading.RLock()
        self._log: deque[SetpointRecord] = deque(maxlen=log_capacity)
        self._dict = build_object_dictionary(config)
        # encoder / velocity conversions (the suite's one place for them); the setpoint scale
        # comes from the drive's own objects (0x6076, 0x3001:05), which a master may rewrite
        self._units = config.units()
        self.node = _DriveNode(self, config.node_id, self._dict)
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        # what the SDO server may serve: on an EPOS4 the objects of its EDS, nothing else
        self._served: Optional[frozenset[tuple[int, int]]] = (
            frozenset(eds_objects()) if self.family == "epos4" else None)
        self._served_indices = frozenset(i for i, _ in self._served or ())
        self._link: Optional[_Link] = None
        self._consumers: dict[int, float] = {}        # node id -> timeout s (0x1016)
        self._hb_seen: dict[int, float] = {}
        self._hb_tripped: set[int] = set()
        self._consumer_stop = threading.Event()
        self._consumer_thread: Optional[threading.Thread] = None
        self.interpolation_supervision = bool(config.interpolation_supervision)
        self.interpolation_faults = 0    # 0x8250 trips of the interpolation supervision so far
        self.interpolation_unjudged = 0  # intervals opened by a SYNC the simulated bus delivered late
        self._warning = False
        self._rpdo_callbacks = False
        self._pending_emcy: list[int] = []
        self.last_error_time = 0.0       # time.monotonic() s of the latest error or communication error
        self.stall_dump = STALL_DUMP_S
        self._reset_application()

    # -- state ------------------------------------------------------------------------------
    def _reset_application(self) -> None:
        with self._lock:
            self.node.data_store.clear()
            self._refresh_settings()
            self.state = State.SWITCH_ON_DISABLED    # transitions 0 and 1 happen at power-on
            self._controlword = 0
            self._setpoint_raw = 0
            self._commanded = 0.0
            self._applied = 0.0
            self._fault_code = 0
            self._error_register = 0
            self._sync_counts: dict[int, int] = {}
            self._tpdo_structs: dict[tuple, struct.Struct] = {}
            self._pending_sync_rpdo: list[Any] = []
            # the latest SYNCs seen and what each latched: an RPDO delivered after a SYNC but
            # stamped before it is latched at the SYNC it was on the bus before
            self._syncs: deque[_SyncLatch] = deque(maxlen=SYNC_HISTORY)
            self.transitions: list[int] = []
            self.state_log: deque[StateChange] = deque(maxlen=1000)
            self._left_enabled_ns = 0
            self._zero_current_ns = 0
            self._ramp: Optional[_Ramp] = None
            self._law_on = False         # the stop ramp's velocity loop runs in the plant
            self._brake = 0.0
            self._tpdo_sent: dict[int, tuple[int, bytes]] = {}   # id(map) -> (monotonic ns, data)
            self._in_rpdo = False
            # interpolation supervision: bus instants (wall ns) of the SYNCs since it was armed,
            # and of the target-carrying RPDOs not yet judged
            self._ip_syncs: deque[tuple[int, bool]] = deque()     # (bus ns, delivered late)
            self._ip_rx: list[int] = []
        self.plant.set_current(0.0, time.monotonic_ns())

    @property
    def node_id(self) -> int:
        return self.config.node_id

    def set_stall_dump(self, seconds: float) -> None:
        """Dump every thread's stack to stderr when no SYNC was handled for ``seconds`` s after
        one was (``STALL_DUMP_S``; 0 = off): what held a stalled drive process."""
        self.stall_dump = max(0.0, float(seconds))
        if self._link is not None:
            self._link.stall.disarm()
            self._link.stall.seconds = self.stall_dump      # from the next SYNC on

    @property
    def link_stats(self) -> LinkStats:
        return self._link.stats if self._link is not None else LinkStats()

    @property
    def nmt_state(self) -> str:
        return self.node.nmt.state

    @property
    def applied_current(self) -> float:
        """A the power stage drives now."""
        return self._applied

    @property
    def fault_code(self) -> int:
        return self._fault_code

    @property
    def last_sync_ns(self) -> int:
        """Bus instant (wall ns) of the last SYNC this drive handled (0: none yet)."""
        return self._syncs[-1].bus if self._syncs else 0

    @property
    def zero_current_ns(self) -> int:
        """``time.monotonic_ns()`` at which the power stage's current last dropped to 0 A (0: never)."""
        return self._zero_current_ns

    @property
    def left_enabled_ns(self) -> int:
        """``time.monotonic_ns()`` at which the drive last left OPERATION ENABLED (0: never)."""
        return self._left_enabled_ns

    @property
    def attached(self) -> bool:
        """Whether the drive is on a network (``attach`` called, ``close`` not yet)."""
        return self._link is not None

    def heartbeat_consumers(self) -> dict[int, float]:
        """Consumed heartbeats (0x1016): producer node id -> timeout (s)."""
        return dict(self._consumers)

    def heartbeats_seen(self) -> dict[int, float]:
        """Producer node id -> ``time.monotonic()`` s of its latest consumed heartbeat."""
        return dict(self._hb_seen)

    def frames_by_id(self) -> dict[int, int]:
        """Frames this drive received per COB-ID since it was attached (empty when detached)."""
        return dict(self._link.rx_by_id) if self._link is not None else {}

    def statusword(self) -> int:
        follows = self.state is State.OPERATION_ENABLED and self._in_current_mode()
        extra = SW_FOLLOWS_COMMAND if follows else 0
        if follows and abs(self._commanded) > self._limit_c:
            extra |= cia402.SW_INTERNAL_LIMIT
        return cia402.encode_statusword(self.state, warning=self._warning, extra=extra)

    def _raw(self, index: int, sub: int = 0) -> Any:
        entry = self._dict[index]
        if isinstance(entry, ODVariable):
            if sub != 0:
                raise KeyError(f"0x{index:04X} is a variable, it has no subindex {sub}")
            obj = entry
        else:
            obj = entry[sub]
        return obj.decode_raw(self.node.get_data(index, sub))

    def _refresh_settings(self) -> None:
        """Cache the drive settings the 1 kHz path needs (re-read after writes to them)."""
        self._mode_c = int(self._raw(0x6060))
        self._qs_c = int(self._raw(0x605A))
        self._fr_c = int(self._raw(0x605E))
        self._qs_decel_c = float(self._raw(0x6085))
        self._slow_decel_c = float(self._raw(0x6084)) if 0x6084 in self._dict else self._qs_decel_c
        self._abort_c = int(self._raw(0x6007))
        ip_value, ip_index = int(self._raw(0x60C2, 1)), int(self._raw(0x60C2, 2))
        self._ip_period_ns = int(round(ip_value * 10.0 ** (ip_index + 9)))
        self._comm_err_c = int(self._raw(0x1029, 1))
        self._limit_c = self._raw(0x3001 if self.family == "epos4" else 0x6410, 2) / 1000.0
        if self.family == "epos4":
            kt = self._raw(0x3001, 5)
            self._scale_c = self._raw(0x6076) / kt / 1000.0 if kt else 0.0
        else:
            self._scale_c = 1.0 / 1000.0

    _SETTINGS = frozenset({0x6060, 0x605A, 0x605E, 0x6084, 0x6085, 0x6007, 0x1029, 0x3001, 0x6410,
                           0x6076, 0x60C2})

    def _mode(self) -> int:
        return self._mode_c

    def _in_current_mode(self) -> bool:
        return self._mode_c == CURRENT_MODE[self.family]

    def current_limit(self) -> float:
        """A: the drive's own output current limit (0x3001:02 / 0x6410:02)."""
        return self._limit_c

    def setpoint_to_current(self, raw: int) -> float:
        """A for a raw setpoint: EPOS4 ‰ of 0x6076 (· 0x6076 / 0x3001:05); EPOS2 mA."""
        return raw * self._scale_c

    def current_to_setpoint(self, amps: float) -> int:
        """Inverse of ``setpoint_to_current`` (rounded to the wire's integer)."""
        return int(round(amps / self._scale_c)) if self._scale_c else 0

    # -- network ----------------------------------------------------------------------------
    def attach(self, network: canopen.Network) -> None:
        """Join ``network`` (connected canopen Network); call ``boot()`` next."""
        if self._link is not None:
            raise RuntimeError(f"drive {self.node_id} is already attached")
        link = self._link = _Link(network, self.faults, self.node_id, self._seed, self.stall_dump)
        # the link offers the Network interface the LocalNode uses (subscribe, send_message, ...)
        self.node.associate_network(cast(canopen.Network, link))
        link.unsubscribe(0, self.node.nmt.on_command)
        link.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
        link.subscribe(0, self._on_nmt)
        link.subscribe(self.node.sdo.rx_cobid, self._on_sdo)
        link.subscribe(0x80, self._on_sync)
        if not self._rpdo_callbacks:
            for m in _maps(self.node.rpdo).values():
                m.add_callback(self._on_rpdo)
            self._rpdo_callbacks = True

    def detach(self) -> None:
        """Leave the network (its bus is gone) without powering down: state, settings and the
        watchdogs stay; ``reattach`` joins another one."""
        self.node.nmt.stop_heartbeat()
        if self._link is not None:
            self._link.close()
            self._link = None
        self.node.remove_network()
        self._consumers = {}          # their subscriptions went with the link

    def bus_lost(self) -> None:
        """The CAN bus is gone (bus off, or the hub this drive joined went away): EMCY 0x81FD
        CAN bus off as a drive error (FAULT, current 0 at once, per ``raise_emcy``), sent once
        the drive is on a bus again. The drive leaves the network."""
        self.detach()
        self.raise_emcy(0x81FD)
        self._pending_emcy.append(0x81FD)

    def reattach(self, network: canopen.Network) -> None:
        """Back on a bus (bus-off recovery; no power cycle, so no boot-up frame): PDOs and heartbeat
        consumers subscribed again, NMT PRE-OPERATIONAL (a communication error, 0x1029:01 = 0 as
        well as 1 and 2 leave no PDOs running here), heartbeat per 0x1017, pending EMCYs sent."""
        self.attach(network)
        self._reload_pdos()
        self._configure_consumers()
        self._hb_seen.clear()
        self._hb_tripped.clear()
        self.node.nmt.send_command(0x80 if self._comm_err_c != 2 else 0x02)
        self.node.nmt.start_heartbeat(int(self._raw(0x1017)))
        for code in self._pending_emcy:
            self.node.emcy.send(code, self.error_register_for(code), b"")
        self._pending_emcy.clear()

    def power_off(self) -> None:
        """Switch the drive off: no current, it hears and sends nothing, settings back to their
        defaults; ``boot()`` powers it on again."""
        self.node.nmt.stop_heartbeat()
        self.faults.unpowered = True
        self._reset_application()

    def boot(self) -> None:
        """Power-on: boot-up frame, PRE-OPERATIONAL, heartbeat per 0x1017."""
        self.faults.unpowered = False
        self._reload_pdos()
        self._refresh_settings()
        self._configure_consumers()
        self._start_watch()
        self.node.nmt.send_command(0x81)     # INITIALISING -> boot-up frame
        self.node.nmt.send_command(0x80)     # PRE-OPERATIONAL, starts heartbeat if 0x1017 > 0

    def close(self) -> None:
        """Stop heartbeat and timers and leave the network (the network itself stays open)."""
        self.node.nmt.stop_heartbeat()
        self._consumer_stop.set()
        if self._link is not None:
            self._link.close()
            self._link = None

    def _reload_pdos(self, which: Optional[tuple[str, int]] = None) -> None:
        """(Re)read PDO maps from the object dictionary; re-subscribe RPDO COB-IDs."""
        link = self._link
        for kind, maps in (("rpdo", _maps(self.node.rpdo)), ("tpdo", _maps(self.node.tpdo))):
            for no, m in maps.items():
                if which is not None and which != (kind, no):
                    continue
                old = m.cob_id if (kind == "rpdo" and m.enabled) else None
                m.read()                              # also subscribes enabled maps
                if link is None:
                    continue
                if kind == "tpdo" and m.enabled:
                    link.unsubscribe(m.cob_id, m.on_message)   # our own transmit PDOs
                if kind == "rpdo":
                    if old is not None and old != m.cob_id:
                        link.unsubscribe(old, m.on_message)
                    if m.enabled:
                        link.subscribe(m.cob_id, m.on_message)
                self._sync_counts.pop(id(m), None)

    # -- SDO hooks ----------------------------------------------------------------------------
    def _live(self, t_ns: int) -> dict[tuple[int, int], Any]:
        """Values of the live objects at ``t_ns``."""
        q, qd, amps = self.plant.sample(t_ns)
        counts = self._units.rad_to_increments(q)
        counts = ((counts + 2**31) % 2**32) - 2**31      # INT32 wraps like the drive's counter
        rpm = self._units.rad_s_to_rpm(qd)
        stopped = qd == 0.0
        with self._lock:
            if (self.state is State.QUICK_STOP_ACTIVE and stopped and self._ramp is None
                    and 1 <= self._qs_c <= 4):
                self._set_state(State.SWITCH_ON_DISABLED, 12, t_ns)   # quick stop done
        ma = int(round(amps * 1000.0))
        vals: dict[tuple[int, int], Any] = {
            (0x6041, 0): self.statusword(),
            (0x6061, 0): self._mode(),
            (0x6064, 0): counts,
            (0x606C, 0): rpm,
            (0x1001, 0): self._error_register,
        }
        if self.family == "epos4":
            vals[(0x30D1, 1)] = vals[(0x30D1, 2)] = ma
            vals[(0x6077, 0)] = max(-32768, min(32767, self.current_to_setpoint(amps)))
        else:
            vals[(0x6078, 0)] = vals[(0x2027, 0)] = max(-32768, min(32767, ma))
        return vals

    _LIVE = {(0x6041, 0), (0x6061, 0), (0x6064, 0), (0x606C, 0), (0x1001, 0), (0x30D1, 1),
             (0x30D1, 2), (0x6077, 0), (0x6078, 0), (0x2027, 0)}

    def _on_read(self, index: int, subindex: int, od: ODVariable) -> Any:
        if (index, subindex) in self._LIVE:
            return self._live(time.monotonic_ns()).get((index, subindex))
        return None

    def _on_write(self, index: int, subindex: int, od: ODVariable, data: bytes) -> None:
        """Validate writes before they are stored (raise SdoAbortedError to refuse)."""
        raw = od.decode_raw(data) if od.data_type in _NUMBER_TYPES else None
        if not isinstance(raw, int):
            return                                   # only integer objects are checked
        value = raw
        if 0x1400 <= index <= 0x15FF or 0x1800 <= index <= 0x19FF:
            self._check_comm_write(index, subindex, value)
        elif 0x1600 <= index <= 0x17FF or 0x1A00 <= index <= 0x1BFF:
            self._check_map_write(index, subindex, value)
        elif index == 0x6060:
            if value not in VALID_MODES[self.family]:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
        elif index == 0x1003 and subindex == 0 and value != 0:
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        elif index == 0x605A and not -1 <= value <= 8:
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        elif index == 0x605E and not 0 <= value <= 2:
            raise SdoAbortedError(ABORT_VALUE_RANGE)

    def _check_comm_write(self, index: int, subindex: int, value: int) -> None:
        """A PDO COB-ID (sub 1): bit 31 not valid, bit 30 no RTR (TxPDOs; maxon writes it set),
        an 11-bit CAN-ID in bits 0-10 (bit 29, a 29-bit id, and bits 11-28 refused)."""
        if subindex != 1:
            return
        if value & 0x3FFFF800:
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        cur = self._raw(index, 1)
        valid_now = not cur & PDO_VALID_BIT
        if valid_now and not value & PDO_VALID_BIT and (value & 0x7FF) != (cur & 0x7FF):
            raise SdoAbortedError(ABORT_VALUE_RANGE)   # change COB-ID only while invalid

    def _check_map_write(self, index: int, subindex: int, value: int) -> None:
        comm = index - 0x200
        if not self._raw(comm, 1) & PDO_VALID_BIT:
            raise SdoAbortedError(ABORT_DEVICE_STATE)  # mapping changes need the PDO disabled
        if subindex == 0:
            if value > 8:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
            bits = 0
            for s in range(1, value + 1):
                entry = self._raw(index, s)
                self._check_entry(entry, receive=index < 0x1A00)
                bits += entry & 0xFF
            if bits > 64:
                raise SdoAbortedError(ABORT_PDO_TOO_LONG)
        else:
            if self._raw(index, 0) != 0:
                raise SdoAbortedError(ABORT_DEVICE_STATE)  # write count 0 before the entries
            if value:
                self._check_entry(value, receive=index < 0x1A00)

    def _check_entry(self, entry: int, receive: bool) -> None:
        idx, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
        if idx not in self._dict:
            raise SdoAbortedError(ABORT_NOT_IN_OD)
        obj = self._dict[idx]
        if not isinstance(obj, ODVariable):
            if sub not in obj:
                raise SdoAbortedError(ABORT_NO_SUBINDEX)
            obj = obj[sub]
        if not obj.pdo_mappable or (receive and not obj.writable) or bits != len(obj):
            raise SdoAbortedError(ABORT_NOT_MAPPABLE)

    def _after_write(self, index: int, subindex: int) -> None:
        """After a write is stored: reload PDO maps, run the drive logic."""
        if index in self._SETTINGS:
            self._refresh_settings()
        if 0x1400 <= index <= 0x17FF:
            self._reload_pdos(("rpdo", (index & 0x1FF) + 1))
        elif 0x1800 <= index <= 0x1BFF:
            self._reload_pdos(("tpdo", (index & 0x1FF) + 1))
        elif index == 0x1016:
            self._configure_consumers()
        elif index == 0x1003 and subindex == 0:
            for s in range(1, 9):
                self.node.data_store.get(0x1003, {}).pop(s, None)
        elif self._in_rpdo:
            return                                   # the RPDO handler applies once at the end
        elif index == 0x6040:
            self._apply_controlword(self._raw(0x6040), time.monotonic_ns())
            self._apply(time.monotonic_ns())
        elif (index, subindex) == SETPOINT_OBJ[self.family]:
            t, w = time.monotonic_ns(), time.time_ns()
            self._setpoint(self._raw(index, subindex), t, w, "sdo")
        elif index in (0x6060, 0x3001, 0x6410, 0x6076):
            self._apply(time.monotonic_ns())

    # -- drive logic --------------------------------------------------------------------------
    def _set_state(self, new: State, transition: int, t_ns: int) -> None:
        was_driving = self.state is State.OPERATION_ENABLED and self._in_current_mode()
        if self.state is State.OPERATION_ENABLED and new is not State.OPERATION_ENABLED:
            self._left_enabled_ns = t_ns
        cleared = False
        if new not in _BRAKING:
            cleared = self._set_ramp(None, t_ns)
        elif transition == 11 and was_driving:
            self._begin_ramp("quick_stop", self._qs_c, t_ns)
        elif transition == 13 and (was_driving or self._ramp is not None):
            self._begin_ramp("fault", self._fr_c, t_ns)
        self.state = new
        self.transitions.append(transition)
        self.state_log.append(StateChange(t_ns, t_ns + wall_minus_mono(),
                                          new, transition))
        if new not in _POWERED or cleared:
            self._apply(t_ns)

    # -- stop ramps (quick stop 0x605A, fault reaction 0x605E) ----------------------------------
    def _begin_ramp(self, kind: str, option: int, t_ns: int) -> None:
        """Brake the motor to standstill under the drive's velocity loop, as an EPOS4 does in CST
        on a quick stop or a fault reaction: 0x605A 1/5 and 0x605E 1 on the slow down ramp
        (0x6084 profile deceleration), 0x605A 2/6 and 0x605E 2 on the quick stop ramp (0x6085
        quick stop deceleration), 0x605A 3/4/7/8 at the current limit; rpm/s of the motor.
        0x605A 0 / 0x605E 0, a motor standing still, or no tuned velocity loop (``load_inertia``
        0): no ramp, the current is cut at once."""
        self._set_ramp(None, t_ns)
        if option <= 0 or (kind == "fault" and option > 2) or self.config.load_inertia <= 0:
            return
        _, qd, _ = self.plant.sample(t_ns)
        if abs(qd) < STANDSTILL:
            return
        slow = option in (1, 5)
        at_limit = kind == "quick_stop" and option in (3, 4, 7, 8)
        decel = self._slow_decel_c if slow else self._qs_decel_c
        if at_limit:
            alpha = math.inf
        elif decel <= 0:
            return
        else:
            alpha = decel * RPM_S / self.config.gear_ratio
        t_ramp = 0.0 if math.isinf(alpha) else abs(qd) / alpha
        ramp = _Ramp(kind, t_ns, qd, alpha, t_max=2.0 * t_ramp + 1.0)
        self._brake = self._ramp_current(ramp, qd, 0.0)
        self._set_ramp(ramp, t_ns)

    def _set_ramp(self, ramp: Optional[_Ramp], t_ns: int) -> bool:
        """Start (``ramp``) or end (None) a stop ramp at ``t_ns``. On a plant that takes a current
        law (``SimArm``) the velocity loop runs in the plant's time, as in a drive's firmware,
        however late this process's threads run (``JointPort.set_law``); True when a law ended
        (the caller then pushes the power stage's current again)."""
        self._ramp = ramp
        set_law = getattr(self.plant, "set_law", None)
        if set_law is None:
            return False
        if ramp is None:
            if not self._law_on:
                return False
            set_law(None, t_ns)
            self._law_on = False
            self._applied = math.nan            # the next _apply pushes its current
            return True
        lim = self.current_limit()

        def law(t: int, _q: float, qd: float) -> float:
            return max(-lim, min(lim, self._ramp_current(ramp, qd, (t - ramp.t0_ns) * 1e-9)))

        set_law(law, t_ns)
        self._law_on = True
        return False

    def _ramp_current(self, r: _Ramp, qd: float, t: float) -> float:
        """A the velocity loop asks for at ``t`` s into the ramp at joint speed ``qd`` rad/s:
        the ramp's deceleration plus the speed error over ``RAMP_TAU``, through J / (n kt)."""
        sign = 1.0 if r.v0 > 0 else -1.0
        v_ref = 0.0 if math.isinf(r.alpha) else sign * max(0.0, abs(r.v0) - r.alpha * t)
        a_ref = -sign * r.alpha if v_ref != 0.0 else 0.0
        torque_per_amp = self.config.gear_ratio * self.config.torque_constant
        return self.config.load_inertia * (a_ref + (v_ref - qd) / RAMP_TAU) / torque_per_amp

    def _ramp_step(self) -> None:
        """One step of a running stop ramp (the drive's own thread): new braking current, or the
        end of the ramp: current 0, then transition 12 (0x605A 1-4) or 14 (fault reaction)."""
        with self._lock:
            r = self._ramp
            if r is None:
                return
            now = time.monotonic_ns()
            _, qd, _ = self.plant.sample(now)
            t = (now - r.t0_ns) * 1e-9
            ramp_over = math.isinf(r.alpha) or abs(r.v0) - r.alpha * t <= 0.0
            stopped = abs(qd) < STANDSTILL or qd * r.v0 < 0.0
            if (ramp_over and stopped) or t > r.t_max:
                self._brake = 0.0
                self._set_ramp(None, now)
                self._apply(now)
                if r.kind == "fault" and self.state is State.FAULT_REACTION_ACTIVE:
                    self._set_state(State.FAULT, 14, now)
                elif self.state is State.QUICK_STOP_ACTIVE and 1 <= self._qs_c <= 4:
                    self._set_state(State.SWITCH_ON_DISABLED, 12, now)
                return
            self._brake = self._ramp_current(r, qd, t)
            self._apply(now)

    @property
    def braking(self) -> bool:
        """True while the drive brakes on a stop ramp."""
        return self._ramp is not None

    def _apply_controlword(self, cw: int, t_ns: int) -> None:
        with self._lock:
            prev, self._controlword = self._controlword, cw
            new, fired = drive_step(self.state, cw, prev, self._qs_c)
            if 15 in fired:
                self._clear_fault()
            for tr in fired:
                self._set_state(new, tr, t_ns)

    def _setpoint(self, raw: int, t_ns: int, wall_ns: int, source: str,
                  record: bool = True) -> None:
        with self._lock:
            self._setpoint_raw = raw
            self._apply(t_ns)
            if record:
                self._log.append(SetpointRecord(t_ns, wall_ns, raw, self._commanded, self._applied,
                                                source))

    def _apply(self, t_ns: int) -> None:
        """Recompute the power stage's current and push it to the plant at ``t_ns``."""
        with self._lock:
            self._commanded = self.setpoint_to_current(self._setpoint_raw)
            lim = self.current_limit()
            amps = max(-lim, min(lim, self._commanded))
            braking = self._ramp is not None and self.state in _BRAKING
            if braking:
                amps = max(-lim, min(lim, self._brake))
            elif self.state not in _POWERED or not self._in_current_mode():
                amps = 0.0
            if braking and self._law_on:
                pass                            # the plant runs the velocity loop's law
            elif amps != self._applied or self._applied == 0.0:
                self.plant.set_current(amps, t_ns)
            if amps == 0.0 and self._applied != 0.0:
                self._zero_current_ns = t_ns
            self._applied = amps

    def reapply(self) -> None:
        """Push the current the power stage drives now into the plant again (after a plant reset)."""
        self._apply(time.monotonic_ns())

    def _on_rpdo(self, pdo_map: Any) -> None:
        link = self._link
        if link is None or self.node.nmt.state != "OPERATIONAL":
            return
        t_ns, wall = link.rx_mono_ns, link.rx_wall_ns
        if any(v.index in self._TARGETS for v in pdo_map.map):
            self._ip_rx.append(link.rx_bus_ns)       # a new target for the supervision
        if pdo_map.trans_type is not None and pdo_map.trans_type <= 240:
            ts = link.rx_bus_ns
            if self._syncs and ts <= self._syncs[-1].bus:
                self._latch_late(pdo_map, bytes(pdo_map.data), ts)
                return
            self._pending_sync_rpdo.append((pdo_map, bytes(pdo_map.data), ts))
            return
        self._take_rpdo(pdo_map, bytes(pdo_map.data), t_ns, wall)

    def _latch_late(self, pdo_map: Any, data: bytes, ts: int) -> None:
        """A synchronous RPDO on the bus at ``ts`` (wall ns) before a SYNC already handled, delivered
        after it (two senders' frames reach a virtual channel in the order they got its lock, not
        of their stamps): latched at the first SYNC at or after ``ts``, as a drive on a real bus
        would have, unless a later-stamped RPDO of the same map was latched there. When a later
        SYNC latched a newer RPDO of that map, the drive goes on with that one (the plant puts the
        late change in its place in its history and replays what followed)."""
        syncs = list(self._syncs)
        k = max(0, bisect.bisect_left([s.bus for s in syncs], ts))
        at = syncs[k]
        prev = at.latched.get(id(pdo_map))
        if prev is not None and prev[0] > ts:
            return
        at.latched[id(pdo_map)] = (ts, data)
        self._take_rpdo(pdo_map, data, at.t_ns, at.bus)
        for later in reversed(syncs[k + 1:]):
            if id(pdo_map) in later.latched:
                self._take_rpdo(pdo_map, later.latched[id(pdo_map)][1], later.t_ns, later.bus,
                                record=False)
                break

    def _take_rpdo(self, pdo_map: Any, data: bytes, t_ns: int, wall: int,
                   record: bool = True) -> None:
        sp_key = SETPOINT_OBJ[self.family]
        with self._lock:
            self._in_rpdo = True
            cw = sp = None
            try:
                store = self.node.data_store
                for var in pdo_map.map:
                    byte0 = var.offset // 8
                    chunk = data[byte0:byte0 + len(var.od) // 8]
                    if var.index in self._SETTINGS:       # validated + cached: full path
                        self.node.set_data(var.index, var.subindex, chunk)
                    else:                                 # plain process data: just store it
                        store.setdefault(var.index, {})[var.subindex] = chunk
                    if var.index == 0x6040:
                        cw = var.od.decode_raw(chunk)
                    elif (var.index, var.subindex) == sp_key:
                        sp = var.od.decode_raw(chunk)
            finally:
                self._in_rpdo = False
            if cw is not None:
                self._apply_controlword(cw, t_ns)
            if sp is not None:
                self._setpoint(sp, t_ns, wall, "rpdo", record)
            else:
                self._apply(t_ns)

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        link = self._link
        if link is None or self.node.nmt.state != "OPERATIONAL":
            return
        # the SYNC's bus instant, on the plant's clock (monotonic): when the drive latches
        bus = link.rx_bus_ns
        t_ns = bus - wall_minus_mono()
        wall = bus
        pending = self._pending_sync_rpdo
        self._pending_sync_rpdo = [p for p in pending if p[2] > bus]   # on the bus after it
        sync = _SyncLatch(bus, t_ns, {})
        self._syncs.append(sync)
        for m, d, ts in sorted((p for p in pending if p[2] <= bus), key=lambda p: p[2]):
            sync.latched[id(m)] = (ts, d)
            self._take_rpdo(m, d, t_ns, wall)
        self._supervise_interpolation(bus, link.rx_lag_ns)
        live: Optional[dict] = None
        for m in _maps(self.node.tpdo).values():
            if not m.enabled or m.trans_type is None or not 1 <= m.trans_type <= 240:
                continue
            n = self._sync_counts.get(id(m), 0) + 1
            if n < m.trans_type:
                self._sync_counts[id(m)] = n
                continue
            self._sync_counts[id(m)] = 0
            if live is None:
                live = self._live(t_ns)
            values = [live[key] if key in live else od_var.decode_raw(self.node.get_data(*key))
                      for key, od_var in self._tpdo_layout(m)]
            link.send_message(m.cob_id, self._tpdo_struct(m).pack(*values))

    _TARGETS = frozenset(CSX_TARGETS.values())

    def _supervise_interpolation(self, bus: int, lag_ns: int = 0) -> None:
        """Interpolation supervision of an EPOS4 in a cyclic synchronous mode (0x6060 8/9/10) in
        OPERATION ENABLED with 0x60C2 set: every SYNC interval (bus instants, wall ns) must bring
        at least one RPDO that carries a target (0x607A / 0x60FF / 0x6071); one without faults
        the drive with EMCY 0x8250 (fault reaction 0x605E, current 0). Armed at the first SYNC
        handled in OPERATION ENABLED; an interval is judged ``SUPERVISION_SLACK_NS`` of SYNCs
        later. Called at each SYNC (``lag_ns``: how long after its bus instant this process got
        it), after the RPDOs it latched.

        An interval opened by a SYNC that reached the drive more than half a period after its bus
        instant is not judged (``interpolation_unjudged`` counts them): the simulated bus (the
        hub's timer, this process) was late, as a real bus is not, and the master, which answers
        that SYNC, could not make the cycle either."""
        period = self._ip_period_ns
        if not (self.interpolation_supervision and period > 0 and self.family == "epos4"
                and self._mode_c in CSX_TARGETS and self.state is State.OPERATION_ENABLED):
            self._ip_syncs.clear()
            self._ip_rx = [t for t in self._ip_rx if t > bus]
            return
        syncs = self._ip_syncs
        syncs.append((bus, lag_ns > period // 2))
        lag = max(1, -(-SUPERVISION_SLACK_NS // period))
        while len(syncs) >= lag + 2:
            lo, late = syncs.popleft()
            hi = syncs[0][0]
            rx = self._ip_rx
            fresh = any(lo < t <= hi for t in rx)
            self._ip_rx = [t for t in rx if t > hi]
            if not fresh and late:
                self.interpolation_unjudged += 1
            elif not fresh:
                syncs.clear()
                self.interpolation_faults += 1
                self.raise_emcy(RPDO_TIMEOUT)
                return

    def _tpdo_layout(self, m: Any) -> list[tuple[tuple[int, int], ODVariable]]:
        return [((v.index, v.subindex), v.od) for v in m.map]

    def _tpdo_struct(self, m: Any) -> struct.Struct:
        """Packer of a TPDO's mapped objects (entries are whole objects, checked on mapping)."""
        key = tuple((v.index, v.subindex) for v in m.map)
        st = self._tpdo_structs.get(key)
        if st is None:
            st = struct.Struct("<" + "".join(v.od.STRUCT_TYPES[v.od.data_type].format.lstrip("<")
                                             for v in m.map))
            self._tpdo_structs[key] = st
        return st

    def _event_tpdos(self) -> None:
        """Event-driven TPDOs (transmission type 254/255, CiA 301): sent when a mapped value
        changed, no sooner than the inhibit time (0x1800+n:03, 100 µs) after the previous one,
        and at least every event timer (0x1800+n:05, ms; 0 = on change only)."""
        link = self._link
        if link is None:
            return
        now = time.monotonic_ns()
        live: Optional[dict] = None
        for m in _maps(self.node.tpdo).values():
            if not m.enabled or m.trans_type not in (254, 255) or not m.map:
                continue
            comm = m.com_record.od.index
            subs = self._dict[comm]
            present = set() if isinstance(subs, ODVariable) else set(subs.subindices)
            inhibit_ns = int(self._raw(comm, 3)) * 100_000 if 3 in present else 0
            timer_ns = int(self._raw(comm, 5)) * 1_000_000 if 5 in present else 0
            last = self._tpdo_sent.get(id(m))
            if last is not None and now - last[0] < inhibit_ns:
                continue
            if live is None:
                live = self._live(now)
            values = [live[key] if key in live else od_var.decode_raw(self.node.get_data(*key))
                      for key, od_var in self._tpdo_layout(m)]
            data = self._tpdo_struct(m).pack(*values)
            if last is None or data != last[1] or (timer_ns and now - last[0] >= timer_ns):
                self._tpdo_sent[id(m)] = (now, data)
                link.send_message(m.cob_id, data)

    def _on_sdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.node.nmt.state == "STOPPED":          # CiA 301: no SDO in STOPPED
            return
        served = self._served
        # initiate download (client command 1) / upload (2): refuse what the EDS lacks
        if served is not None and len(data) >= 4 and data[0] >> 5 in (1, 2):
            index, sub = struct.unpack_from("<HB", data, 1)
            if (index, sub) not in served:
                code = ABORT_NO_SUBINDEX if index in self._served_indices else ABORT_NOT_IN_OD
                if self._link is not None:
                    self._link.send_message(self.node.sdo.tx_cobid,
                                            struct.pack("<BHBL", 0x80, index, sub, code))
                return
        self.node.sdo.on_request(can_id, data, timestamp)

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) < 2:
            return
        cmd, nid = data[0], data[1]
        if nid not in (0, self.node_id):
            return
        if cmd == 0x81:
            self.reset_node()
        elif cmd == 0x82:
            self.reset_communication()
        elif cmd in (0x01, 0x02, 0x80):
            self.node.nmt.on_command(can_id, data, timestamp)

    def reset_node(self) -> None:
        """NMT reset node: application and communication back to defaults, boot-up again."""
        self.node.nmt.stop_heartbeat()
        self._reset_application()
        self.boot()

    def reset_communication(self) -> None:
        """NMT reset communication: 0x1000-0x1FFF back to defaults, boot-up again."""
        self.node.nmt.stop_heartbeat()
        for idx in [i for i in self.node.data_store if 0x1000 <= i <= 0x1FFF and i not in (0x1001, 0x1003)]:
            del self.node.data_store[idx]
        self.boot()

    # -- heartbeat consumer ---------------------------------------------------------------------
    def _configure_consumers(self) -> None:
        """(Re)read 0x1016 and watch the heartbeats it names."""
        wanted: dict[int, float] = {}
        for sub in range(1, 5):
            v = self._raw(0x1016, sub)
            nid, ms = (v >> 16) & 0x7F, v & 0xFFFF
            if nid and ms and nid != self.node_id:
                wanted[nid] = ms / 1000.0
        if self._link is not None:
            for nid in set(self._consumers) - set(wanted):
                self._link.unsubscribe(0x700 + nid, self._on_consumed_heartbeat)
            for nid in set(wanted) - set(self._consumers):
                self._link.subscribe(0x700 + nid, self._on_consumed_heartbeat)
        self._consumers = wanted
        for nid in list(self._hb_seen):
            if nid not in wanted:
                del self._hb_seen[nid]

    def _start_watch(self) -> None:
        if self._consumer_thread is None or not self._consumer_thread.is_alive():
            self._consumer_stop.clear()
            self._consumer_thread = threading.Thread(target=self._watch, daemon=True,
                                                     name=f"epos{self.node_id}-watchdogs")
            self._consumer_thread.start()

    def _on_consumed_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        nid = can_id - 0x700
        self._hb_seen[nid] = time.monotonic()
        self._hb_tripped.discard(nid)

    def _watch(self) -> None:
        """The drive's own thread (every 2 ms): stop ramps, event-driven TPDOs, consumed
        heartbeats."""
        while not self._consumer_stop.wait(0.002):
            nmt = self.node.nmt.state
            try:
                self._ramp_step()
                if nmt == "OPERATIONAL":
                    self._event_tpdos()
            except Exception:  # noqa: BLE001 - a frame that cannot go out must not end the watchdogs
                pass
            if nmt not in ("PRE-OPERATIONAL", "OPERATIONAL"):
                continue
            now = time.monotonic()
            for nid, limit in list(self._consumers.items()):
                seen = self._hb_seen.get(nid)
                if seen is not None and now - seen > limit and nid not in self._hb_tripped:
                    self._hb_tripped.add(nid)
                    self.communication_error(0x8130, bytes([nid]))   # heartbeat error

    def communication_error(self, code: int, data: bytes = b"") -> None:
        """A communication error (e.g. heartbeat 0x8130): the reaction of 0x6007 abort
        connection option, EMCY, then the NMT state of 0x1029:01."""
        self.last_error_time = time.monotonic()
        option = self._abort_c
        if option == 1:
            self.raise_emcy(code, data=data)                       # fault signal
        else:
            t = time.monotonic_ns()
            with self._lock:
                if option == 2 and self.state in (State.READY_TO_SWITCH_ON, State.SWITCHED_ON,
                                                  State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE):
                    self._apply_controlword(cia402.CONTROLWORD[Command.DISABLE_VOLTAGE], t)
                elif option == 3 and self.state in (State.READY_TO_SWITCH_ON, State.SWITCHED_ON,
                                                    State.OPERATION_ENABLED):
                    self._apply_controlword(cia402.CONTROLWORD[Command.QUICK_STOP], t)
            self._send_emcy(code, self.error_register_for(code), data)
        if self._comm_err_c == 0 and self.node.nmt.state == "OPERATIONAL":
            self.node.nmt.send_command(0x80)                       # -> PRE-OPERATIONAL
        elif self._comm_err_c == 2:
            self.node.nmt.send_command(0x02)                       # -> STOPPED

    def raise_warning(self, code: int = 0xFF01, data: bytes = b"") -> None:
        """A warning (e.g. 0xFF01): EMCY sent, statusword bit 7 set; the state stays."""
        if not 0x1000 <= code <= 0xFFFF:
            raise SimConfigError(f"EMCY code must be 0x1000..0xFFFF, got {code:#x}")
        self._warning = True
        self._send_emcy(code, 0x00, data)

    def clear_warning(self) -> None:
        """The warning condition is gone: statusword bit 7 cleared, EMCY error reset."""
        self._warning = False
        self._send_emcy(0x0000, self._error_register, b"")

    def _send_emcy(self, code: int, register: int, data: bytes) -> None:
        if self._link is not None and self.node.nmt.state in ("PRE-OPERATIONAL", "OPERATIONAL"):
            self.node.emcy.send(code, register, bytes(data)[:5])

    # -- faults -------------------------------------------------------------------------------
    @staticmethod
    def error_register_for(code: int) -> int:
        """CiA 301 error register bits for an EMCY code: bit 0 generic + the code's category."""
        reg = 0x01
        top = code & 0xF000
        reg |= {0x2000: 0x02, 0x3000: 0x04, 0x4000: 0x08, 0x8000: 0x10}.get(top, 0)
        if code & 0xFF00 == 0xFF00 or top in (0x5000, 0x6000, 0x7000):
            reg |= 0x80
        return reg

    def raise_emcy(self, code: int = 0x1000, register: Optional[int] = None,
                   data: bytes = b"") -> None:
        """Drive fault: transitions 13/14 to FAULT, current 0, EMCY (code, register) sent."""
        if not 0x1000 <= code <= 0xFFFF:
            raise SimConfigError(f"EMCY code must be 0x1000..0xFFFF, got {code:#x}")
        t = time.monotonic_ns()
        reg = self.error_register_for(code) if register is None else int(register) & 0xFF
        self.last_error_time = time.monotonic()
        with self._lock:
            self._fault_code, self._error_register = code, reg     # before the state: readers
            if self.state not in (State.FAULT, State.FAULT_REACTION_ACTIVE):   # see the code
                self._set_state(State.FAULT_REACTION_ACTIVE, 13, t)            # with Fault
                if self._ramp is None:          # 0x605E 1/2 on a moving motor: brake first
                    self._set_state(State.FAULT, 14, t)
            self.node.data_store.setdefault(0x603F, {})[0] = struct.pack("<H", code)
            hist = self.node.data_store.setdefault(0x1003, {})
            old = [struct.unpack("<L", hist[s])[0] for s in range(1, 9) if s in hist]
            new = ([code] + old)[:8]
            for s, v in enumerate(new, 1):
                hist[s] = struct.pack("<L", v)
            hist[0] = bytes([len(new)])
        if self._link is not None and self.node.nmt.state in ("PRE-OPERATIONAL", "OPERATIONAL"):
            self.node.emcy.send(code, reg, bytes(data)[:5])

    def _clear_fault(self) -> None:
        self._fault_code, self._error_register = 0, 0
        self._warning = False
        self.node.data_store.setdefault(0x603F, {})[0] = struct.pack("<H", 0)
        if self._link is not None:
            self.node.emcy.reset(0)

    def stop_heartbeat(self, stopped: bool = True) -> None:
        """Fault: stop (or resume) producing heartbeats without changing 0x1017."""
        self.faults.heartbeat_stopped = bool(stopped)

    def set_sdo_silent(self, silent: bool = True) -> None:
        """Fault: ignore (or answer again) SDO requests."""
        self.faults.sdo_silent = bool(silent)

    def set_delay(self, ms: float, direction: str = "both") -> None:
        """Fault: delay frames to ('rx'), from ('tx') or both ways by ``ms`` milliseconds."""
        if not (ms >= 0 and math.isfinite(ms)):
            raise SimConfigError(f"delay must be >= 0 ms, got {ms}")
        for d in self.directions(direction):
            setattr(self.faults, f"{d}_delay_s", ms / 1000.0)

    def drop_fraction(self, fraction: float, direction: str = "rx") -> None:
        """Fault: drop each frame with probability ``fraction`` (0..1)."""
        if not 0.0 <= fraction <= 1.0:
            raise SimConfigError(f"drop fraction must be in 0..1, got {fraction}")
        for d in self.directions(direction):
            setattr(self.faults, f"{d}_drop_fraction", float(fraction))

    def drop_next(self, n: int, direction: str = "rx") -> None:
        """Fault: drop the next ``n`` frames."""
        if int(n) < 0:
            raise SimConfigError(f"number of frames to drop must be >= 0, got {n}")
        for d in self.directions(direction):
            setattr(self.faults, f"{d}_drop_next", int(n))

    def clear_injected_faults(self) -> None:
        """Remove every injected communication fault (a drive FAULT needs a fault reset)."""
        for k, v in FaultSettings().__dict__.items():
            setattr(self.faults, k, v)

    @staticmethod
    def directions(direction: str) -> tuple[str, ...]:
        """The link directions a fault setting names: 'rx', 'tx' or 'both' (SimConfigError else)."""
        if direction not in ("rx", "tx", "both"):
            raise SimConfigError(f"direction must be 'rx', 'tx' or 'both', got {direction!r}")
        return ("rx", "tx") if direction == "both" else (direction,)

    # -- records ------------------------------------------------------------------------------
    def setpoint_log(self) -> list[SetpointRecord]:
        """Every received setpoint so far (oldest first, up to ``log_capacity``)."""
        with self._lock:
            return list(self._log)

    def clear_setpoint_log(self) -> None:
        with self._lock:
            self._log.clear()



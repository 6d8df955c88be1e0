"""What the parts of :class:`~ff_hwbridge.drive.epos.EposMaster` share: the per-drive record
(:class:`_Drive`), the master's state as one base class (:class:`MasterBase`: the attributes every
part reads, and the methods one part calls in another), the CANopen constants and the errors.

The master is split by concern as ros2_canopen splits its CiA 402 driver: boot and configuration
(``drive.boot``), the state machine (``drive.state_machine``), the feedback receiver
(``drive.tpdo``), the watchdogs and the safe state (``drive.watchdogs``) and the setpoint RPDO
writer (``drive.rpdo``); ``drive.epos`` composes them with the connection, SYNC and heartbeat.
"""
from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import canopen

from ff_hwbridge.drive.config import BridgeConfig, JointConfig
from ff_hwbridge.drive.feedback import JointFeedback, SamplePairing
from ff_hwbridge.drive.safety import SafeCommand, SafetyGuard
from ff_hwbridge.drive.sync_watch import SyncWatch
from ff_hwbridge.protocol.cia402 import State
from ff_hwbridge.protocol.units import DriveUnits

__all__ = ["ABORT_NO_OBJECT", "ECHO_INTERFACES", "NMT_STATES", "OPTIONAL_SUBS", "REFRESH_PERIOD",
           "RESEND_PERIOD", "SYNC_COB_ID", "EposError", "MasterBase", "PreparedCommand", "RpdoChannel"]

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
class RpdoChannel:
    """One drive's setpoint RPDO1 (written by ``drive.rpdo.SetpointRpdos``): its layout, the
    value in force and its counters.

    fmt: struct format (controlword, raw setpoint; ``protocol.epos_od.rpdo_layout``);
    raw_limit: the raw setpoint limit (|raw| <= raw_limit, the configured current limit)."""

    cob_id: int
    fmt: str = "<Hh"
    raw_limit: int = 0
    controlword: int = 0          # the value in force
    setpoint: int = 0             # raw, as sent (clamped)
    cycle_sent: int = -1          # SYNC count (SyncWatch) seen when the latest RPDO was sent
    repeats: int = 0              # RPDOs repeating the value in force (nothing new in a cycle)
    tx_seq: int = 0               # RPDOs handed to the bus
    tx_failing: int = 0           # sends failed since the last that went through
    last_tx: float = 0.0          # clock s of the latest send
    echo_seq: int = 0             # of ours, echoed back by the bus
    echo_log: dict[int, int] = field(default_factory=dict)     # RPDO number -> bus ns
    unechoed: deque[tuple[int, bytes]] = field(default_factory=lambda: deque(maxlen=1024))


@dataclass
class _Drive:
    cfg: JointConfig
    units: DriveUnits
    node: Any = None
    tx1_fmt: str = "<Hi"
    tx2_fmt: str = "<ii"
    target: State = State.SWITCH_ON_DISABLED
    feedback: JointFeedback = field(default_factory=JointFeedback)
    nmt_state: Optional[str] = None
    last_heartbeat: Optional[float] = None
    boot_count: int = 0
    last_boot: float = 0.0
    reset_until: float = 0.0      # monotonic s: Fault is expected (fault reset in progress)
    operational: bool = False
    seen_operational: bool = False
    tpdo_seen: bool = False
    pairing: Optional[SamplePairing] = None   # TPDO1 <-> SYNC (the sample instant)
    emcy: deque = field(default_factory=lambda: deque(maxlen=20))   # recent EMCY texts
    warnings: deque = field(default_factory=lambda: deque(maxlen=20))  # recent warning EMCYs
    history_wanted: bool = False  # read 0x1003 / 0x603F (monitor thread) after a fault
    error_history: str = ""       # decoded 0x1003 / 0x603F, newest first
    notes: list = field(default_factory=list)   # drive settings that could not be applied
    envelope_armed: bool = True   # False after a fault reset outside the envelope
    consumer_armed: bool = False  # 0x1016:01 consumes this master's heartbeat (disarmed on exit)
    limited_armed: bool = False   # a motion has started: bit 11 counts until the next one starts
    limited_count: int = 0        # TPDO1s with statusword bit 11 (internal limit) in this motion
    limited_first_ns: int = 0     # wall ns (sample instant) of the first of them; 0: none
    index: int = 0                # position in the master's drive list
    # the setpoint RPDO1 (``drive.rpdo``): layout, value in force, counters, echoes
    rpdo: RpdoChannel = field(init=False, repr=False, compare=False)

    @property
    def node_id(self) -> int:
        return self.cfg.node_id


class MasterBase:
    """The master's shared state (set up by ``EposMaster.__init__``) and the methods its parts
    call in one another (implemented in the part named)."""

    config: BridgeConfig
    clock: Callable[[], float]
    guard: SafetyGuard
    network: Optional[canopen.Network]
    sync_watch: SyncWatch
    events: deque[tuple[float, str]]
    pending_fn: Callable[[], bool]
    gate_listener: Optional[Callable[[], None]]
    external_player: bool
    echo: bool
    tx_errors: int
    reset_epoch_ns: int
    _drives: list[_Drive]
    _fault_listeners: list[Callable[[str], None]]
    _send_lock: threading.RLock
    _sdo_lock: threading.RLock
    _fb_lock: threading.Lock
    _monitor: Optional[threading.Thread]
    _monitor_stop: threading.Event
    _bus_lost_told: bool
    _configured: bool
    _sync_expected_since: Optional[float]

    # --- boot ------------------------------------------------------------------------------------
    def _configure_drive(self, d: _Drive) -> None:
        raise NotImplementedError

    def read_error_history(self, joint: str) -> str:
        raise NotImplementedError

    # --- watchdogs -------------------------------------------------------------------------------
    def trip(self, reason: str) -> Optional[str]:
        raise NotImplementedError

    # --- state machine ---------------------------------------------------------------------------
    def _step(self, d: _Drive, now: float) -> None:
        raise NotImplementedError

    def _gate_changed(self) -> None:
        raise NotImplementedError

    def _player_owns(self, d: _Drive) -> bool:
        raise NotImplementedError

    # --- RPDO writer -----------------------------------------------------------------------------
    def _send_rpdo(self, d: _Drive, controlword: int, setpoint: int) -> None:
        raise NotImplementedError

    def _send_sdo_controlword(self, d: _Drive, controlword: int) -> None:
        raise NotImplementedError

    def _sync_fresh(self) -> bool:
        raise NotImplementedError

    def command_zero(self) -> None:
        raise NotImplementedError

    def _make_echo_cb(self, d: _Drive) -> Callable[[int, bytearray, float], None]:
        raise NotImplementedError

    # --- feedback --------------------------------------------------------------------------------
    def _publish(self, d: _Drive, **changes: Any) -> JointFeedback:
        raise NotImplementedError

    def _make_tpdo1_cb(self, d: _Drive) -> Callable[[int, bytearray, float], None]:
        raise NotImplementedError

    def _make_tpdo2_cb(self, d: _Drive) -> Callable[[int, bytearray, float], None]:
        raise NotImplementedError

    # --- epos ------------------------------------------------------------------------------------
    def _connected_network(self) -> canopen.Network:
        raise NotImplementedError

    @property
    def sync_expected(self) -> bool:
        raise NotImplementedError

"""Bridge configuration: the CAN bus, the joints' drives, timing and safety limits (from YAML).

Example (``config/bridge_epos4_1dof.yaml``)::

    bus: {interface: socketcan, channel: can0, bitrate: 1000000}
    sync_period: 0.01             # s, SYNC producer period (TPDOs come on every SYNC): 10 ms is
                                  #   the supported rate from Python; 1 ms only experimental
    heartbeat_producer_ms: 10     # ms, written to each drive's 0x1017
    timeout_margin: 0.1           # s, scheduling margin of the derived timeouts below
    heartbeat_timeout: 0          # s, no heartbeat this long -> safe state
                                  #   (0: 3 x heartbeat_producer_ms + timeout_margin)
    master_heartbeat_ms: 100      # ms, > 0: the master produces a heartbeat (id master_node_id,
                                  #   default 127) and each drive consumes it (0x1016:01): if the
                                  #   bridge process dies, the drives fault by themselves (0x8130)
    master_heartbeat_timeout_ms: 0  # ms, the drives' consumer time (0 = max(3 x master_heartbeat_ms,
                                  #   heartbeat_timeout): as patient with the master as it is with them)
    rpdo_timeout_ms: 500          # ms, RxPDO1 event timer 0x1400:05 where a drive has it
                                  #   (maxon's EPOS4 EDS does not): nothing relies on it, the
                                  #   drive's interpolation supervision (0x60C2, EMCY 0x8250)
                                  #   stops it when the master hangs; 0 = off;
                                  #   absent: max(500, 2 x heartbeat_timeout)
    quick_stop_option: 2          # 0x605A: 0 disable drive at once; 1/2 stop on the profile /
                                  #   quick stop ramp, then Switch on disabled; 5/6 same, then
                                  #   stay in Quick stop active (maxon default 6)
    fault_reaction_option: 2      # 0x605E: 0 disable drive (motor free); 1 slow down ramp;
                                  #   2 quick stop ramp (maxon default)
    abort_connection_option: 1    # 0x6007 on a communication error (heartbeat, RPDO timeout):
                                  #   0 none; 1 fault; 2 disable voltage; 3 quick stop (maxon 3)
    communication_error_behaviour: 0  # 0x1029:01 NMT state after a communication error:
                                  #   0 pre-operational (maxon default); 1 unchanged; 2 stopped
    scaling_source: check         # motor data: 'check' (read from the drive, refuse configure on
                                  #   disagreement > scaling_tolerance), 'drive' (use the drive's),
                                  #   'config' (write this file's to the drive)
    scaling_tolerance: 0.01       # relative
    boot_wait: 10.0               # s, keep resetting (every boot_timeout) until the drive boots
    check_identity: true          # 0x1000 device profile 402, 0x1018:01 vendor maxon (0xFB)
    setpoint_timeout: 0.5         # s, no fresh setpoint this long during a motion -> safe state
    spin_margin: 0.0003           # s, the setpoint scheduler sleeps until this long before a stamp
    scheduler_rt_priority: -1     # 1..99: SCHED_FIFO for the setpoint player's thread and the bus
                                  #   receiver (needs CAP_SYS_NICE; falls back with a warning);
                                  #   0 = normal; -1 = auto: 50 with setpoint_timing sync, else 0
    feedback_timeout: 0           # s, no TPDO this long while SYNC runs -> safe state
                                  #    (0: max(3 x sync_period x feedback_every + timeout_margin,
                                  #    heartbeat_timeout))
    feedback_every: 1             # SYNCs per TPDO (status, motion): their transmission type
                                  #   1..240 (CiA 301); e.g. 10 at a 1 kHz SYNC for 100 Hz feedback
    setpoint_timing: sync         # 'sync': setpoint RPDO transmission type 1, latched by the drive
                                  #   at the next SYNC, sent during the cycle before (0x60C2 =
                                  #   sync_period); 'on_receipt': type 255, applied on arrival
    sync_producer: master         # 'master': this bridge produces SYNC (the kernel's broadcast
                                  #   manager on socketcan, else a slot-keeping thread,
                                  #   drive.sync_sender); 'external':
                                  #   another node does (the simulation's CAN hub, a PLC)
    sync_timeout: 0               # s, no SYNC seen this long -> safe state
                                  #   (0: max(3 x sync_period + timeout_margin, heartbeat_timeout))
    missed_cycle_tolerance: 1     # cycles: a setpoint that takes effect more than this many
                                  #   SYNC cycles after its own -> safe state (every miss counts)
    player_process: false         # sync: the setpoint player (guard, units, RPDO, SYNC watch) in
                                  #   its own process with its own bus connection
                                  #   (ff_hwbridge.drive.player_process); false: a thread here
    setpoint_lead: 0.0            # s: no longer used (accepted with a warning): every setpoint
                                  #   is sent by the player itself in the cycle before its SYNC
    stall_dump: 0.0               # s: the setpoint cycle away this long while setpoints are
                                  #   pending -> every thread's stack to stderr (0 = off)
    joints:
      - name: joint1
        node_id: 1
        family: epos4
        current_limit: 10.0       # A, every command is clamped to this
        units: {nominal_current: 3.0, torque_constant: 0.0267, counts_per_rev: 2048, gear_ratio: 54}
        eds: /path/to/EPOS4.eds       # optional: the drive's EDS/DCF instead of the built-in dictionary
        position_limits: [-3.2, 3.2]  # rad, optional: outside -> safe state
        velocity_limit: 20.0          # rad/s, optional: |velocity| above -> safe state

Times are in s unless the name ends in ``_ms``; currents in A.
"""
from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence, Union

import yaml

from ff_hwbridge.protocol.epos_od import CURRENT_MODE
from ff_hwbridge.protocol.units import FAMILIES, DriveUnits, UnitsError

log = logging.getLogger(__name__)


class ConfigError(ValueError):
    """A bridge configuration that cannot be used; the message names the key and what to change."""


# canopen's 0x6060 values per family
MODE_OF_OPERATION = CURRENT_MODE            # 0x6060 per family (epos_od)


@dataclass(frozen=True)
class BusConfig:
    """A python-can bus: interface (socketcan, pcan, kvaser, slcan, remote, virtual), channel,
    bitrate (bit/s) and any other python-can keyword arguments."""

    interface: str = "virtual"
    channel: Optional[str] = "ff-bridge"
    bitrate: int = 1_000_000
    kwargs: Mapping[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """The keyword arguments for ``can.Bus`` / ``drive.bus.open_bus``."""
        out: dict[str, Any] = {"interface": self.interface, "bitrate": int(self.bitrate)}
        if self.channel is not None:
            out["channel"] = self.channel
        out.update(self.kwargs)
        return out


@dataclass(frozen=True)
class JointConfig:
    """One joint = one drive on the bus.

    name:                  joint name (JointState, order of setpoint currents).
    node_id:               CANopen node id 1..127.
    family:                'epos4' (CST, mode 10) or 'epos2' (current mode, -3).
    current_limit:         A, every command is clamped to +-this.
    units:                 conversions (DriveUnits); family is taken from here.
    read_motor_data:       on configure, read nominal current / torque constant from the drive
                           (EPOS4 0x3001:01/:05, EPOS2 0x6410:01) instead of trusting the YAML
                           (the same as ``scaling_source: drive`` for this joint).
    position_limits:       (low, high) rad joint envelope, None = none: outside -> safe state.
    velocity_limit:        rad/s, None = none: |joint velocity| above it -> safe state.
    write_current_limit:   on configure, also write the drive's own output current limit
                           (EPOS4 0x3001:02, EPOS2 0x6410:02) = current_limit.
    eds:                   path of the drive's EDS/DCF (CiA 306, e.g. maxon's file for its
                           firmware): the master's object dictionary is read from it (checked
                           on connect for every object the master uses) instead of the built-in
                           one; None = built in.
    """

    name: str
    node_id: int
    current_limit: float
    units: DriveUnits
    read_motor_data: bool = False
    write_current_limit: bool = True
    position_limits: Optional[tuple[float, float]] = None
    velocity_limit: Optional[float] = None
    eds: Optional[str] = None

    @property
    def family(self) -> str:
        return self.units.family

    @property
    def mode_of_operation(self) -> int:
        return MODE_OF_OPERATION[self.units.family]


#: (key, lowest, highest) of the integer drive settings (objects: see the module docstring)
OPTION_RANGES = (("rpdo_timeout_ms", 0, 65535), ("quick_stop_option", 0, 8),
                 ("fault_reaction_option", 0, 4), ("abort_connection_option", 0, 3),
                 ("communication_error_behaviour", 0, 2))
SCALING_SOURCES = ("check", "drive", "config")
SETPOINT_TIMINGS = ("sync", "on_receipt")
AUTO_RT_PRIORITY = 50       # SCHED_FIFO priority of the synchronous player (scheduler_rt_priority -1)
SYNC_PRODUCERS = ("master", "external")
#: s, what a derived timeout allows beyond its frames' periods: a process on a loaded machine is
#: held off the CPU for tens of ms (40-66 ms seen on the shared 2-core machine)
TIMEOUT_MARGIN = 0.1
#: periods of a producer a derived timeout spans (two frames in a row may be late or lost)
TIMEOUT_PERIODS = 3


def derived_timeout(period: float, margin: float) -> float:
    """s: no frame of a producer with ``period`` (s) for ``TIMEOUT_PERIODS`` periods plus
    ``margin`` (s, scheduling)."""
    return TIMEOUT_PERIODS * float(period) + float(margin)


@dataclass(frozen=True)
class BridgeConfig:
    """Everything the master needs. See the module docstring for the YAML form."""

    bus: BusConfig
    joints: tuple[JointConfig, ...]
    sync_period: float = 0.01
    heartbeat_producer_ms: int = 10
    master_heartbeat_ms: int = 100
    master_heartbeat_timeout_ms: int = 0
    rpdo_timeout_ms: Optional[int] = None      # None: max(500, 2 x heartbeat_timeout) ms
    quick_stop_option: int = 2
    fault_reaction_option: int = 2
    abort_connection_option: int = 1
    communication_error_behaviour: int = 0
    scaling_source: str = "check"
    scaling_tolerance: float = 0.01
    boot_wait: float = 10.0
    check_identity: bool = True
    master_node_id: int = 127
    heartbeat_timeout: float = 0.0
    timeout_margin: float = TIMEOUT_MARGIN
    setpoint_timeout: float = 0.5
    feedback_timeout: float = 0.0
    feedback_every: int = 1
    sdo_timeout: float = 0.5
    boot_timeout: float = 2.0
    state_timeout: float = 1.0
    monitor_period: float = 0.002
    spin_margin: float = 0.0003
    scheduler_rt_priority: int = -1
    reset_communication: bool = True
    setpoint_timing: str = "sync"
    sync_producer: str = "master"
    sync_timeout: float = 0.0
    missed_cycle_tolerance: int = 1
    player_process: bool = False
    setpoint_lead: float = 0.0
    stall_dump: float = 0.0

    @property
    def rt_priority(self) -> int:
        """SCHED_FIFO priority of the player's thread and the bus receiver (0 = normal)."""
        if self.scheduler_rt_priority >= 0:
            return self.scheduler_rt_priority
        return AUTO_RT_PRIORITY if self.synchronous else 0

    @property
    def synchronous(self) -> bool:
        """Setpoint RPDOs are synchronous (transmission type 1, latched at SYNC)."""
        return self.setpoint_timing == "sync"

    def __post_init__(self) -> None:
        if not self.joints:
            raise ConfigError("joints: at least one joint is needed")
        ids = [j.node_id for j in self.joints]
        if len(set(ids)) != len(ids):
            raise ConfigError(f"joints: node ids must differ, got {ids}")
        names = [j.name for j in self.joints]
        if len(set(names)) != len(names):
            raise ConfigError(f"joints: names must differ, got {names}")
        if not (isinstance(self.feedback_every, int) and not isinstance(self.feedback_every, bool)
                and 1 <= self.feedback_every <= 240):
            raise ConfigError("feedback_every must be an integer 1..240 SYNCs (the TPDOs' "
                              f"transmission type), got {self.feedback_every!r}")
        if not (isinstance(self.timeout_margin, (int, float)) and 0.0 <= self.timeout_margin <= 10.0):
            raise ConfigError(f"timeout_margin must be 0 .. 10 s, got {self.timeout_margin!r}")
        # derived timeouts: the producer's period x TIMEOUT_PERIODS + timeout_margin; the SYNC
        # and feedback ones at least as patient as the heartbeat's (a patient configuration)
        if self.heartbeat_timeout == 0.0 and isinstance(self.heartbeat_producer_ms, int):
            object.__setattr__(self, "heartbeat_timeout",
                               derived_timeout(self.heartbeat_producer_ms / 1000.0, self.timeout_margin))
        if self.feedback_timeout == 0.0:
            object.__setattr__(self, "feedback_timeout",
                               max(float(self.heartbeat_timeout),
                                   derived_timeout(float(self.sync_period) * self.feedback_every,
                                                   self.timeout_margin)))
        if self.sync_timeout == 0.0:
            object.__setattr__(self, "sync_timeout",
                               max(float(self.heartbeat_timeout),
                                   derived_timeout(float(self.sync_period), self.timeout_margin)))
        if self.setpoint_timing not in SETPOINT_TIMINGS:
            raise ConfigError(f"setpoint_timing must be one of {SETPOINT_TIMINGS}, got "
                              f"{self.setpoint_timing!r}")
        if self.sync_producer not in SYNC_PRODUCERS:
            raise ConfigError(f"sync_producer must be one of {SYNC_PRODUCERS}, got "
                              f"{self.sync_producer!r}")
        if not (isinstance(self.missed_cycle_tolerance, int) and not isinstance(self.missed_cycle_tolerance, bool)
                and 0 <= self.missed_cycle_tolerance <= 1000):
            raise ConfigError("missed_cycle_tolerance must be an integer 0..1000 cycles, got "
                              f"{self.missed_cycle_tolerance!r}")
        for key in ("sync_period", "heartbeat_timeout", "setpoint_timeout", "feedback_timeout", "sdo_timeout",
                    "boot_timeout", "state_timeout", "monitor_period", "sync_timeout"):
            v = getattr(self, key)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"{key} must be a number of seconds > 0, got {v!r}")
        if not (isinstance(self.stall_dump, (int, float)) and 0.0 <= self.stall_dump <= 3600.0):
            raise ConfigError(f"stall_dump must be 0 .. 3600 s (0 = off), got {self.stall_dump!r}")
        if not (isinstance(self.setpoint_lead, (int, float)) and 0.0 <= self.setpoint_lead <= 0.25):
            raise ConfigError(f"setpoint_lead must be 0 .. 0.25 s (no longer used), got {self.setpoint_lead!r}")
        if self.setpoint_lead > 0:
            log.warning("setpoint_lead %g s is no longer used: every setpoint is sent by the player "
                        "itself in the cycle before its SYNC (remove the key)", self.setpoint_lead)
        if not 0 <= self.spin_margin < 0.05:
            raise ConfigError(f"spin_margin must be in [0, 0.05) s, got {self.spin_margin!r}")
        if not (isinstance(self.heartbeat_producer_ms, int) and 0 < self.heartbeat_producer_ms <= 65535):
            raise ConfigError("heartbeat_producer_ms must be an integer 1..65535 ms, got "
                              f"{self.heartbeat_producer_ms!r}")
        if not (isinstance(self.master_heartbeat_ms, int) and 0 <= self.master_heartbeat_ms <= 20000):
            raise ConfigError("master_heartbeat_ms must be an integer 0..20000 ms (0 = off), got "
                              f"{self.master_heartbeat_ms!r}")
        if not (isinstance(self.master_node_id, int) and 1 <= self.master_node_id <= 127):
            raise ConfigError(f"master_node_id must be an integer 1..127, got {self.master_node_id!r}")
        if self.master_heartbeat_ms and self.master_node_id in [j.node_id for j in self.joints]:
            raise ConfigError(f"master_node_id {self.master_node_id} is also a drive's node id; "
                              "choose an unused id for the master's heartbeat")
        if self.master_heartbeat_timeout_ms == 0 and self.master_heartbeat_ms:
            object.__setattr__(self, "master_heartbeat_timeout_ms",
                               min(65535, max(3 * self.master_heartbeat_ms,
                                              int(round(self.heartbeat_timeout * 1000.0)))))
        if self.rpdo_timeout_ms is None:
            object.__setattr__(self, "rpdo_timeout_ms",
                               min(65535, max(500, int(round(2000.0 * self.heartbeat_timeout)))))
        if not (isinstance(self.master_heartbeat_timeout_ms, int)
                and 0 <= self.master_heartbeat_timeout_ms <= 65535
                and (self.master_heartbeat_timeout_ms > self.master_heartbeat_ms
                     or not self.master_heartbeat_ms)):
            raise ConfigError("master_heartbeat_timeout_ms must be an integer ms above "
                              f"master_heartbeat_ms ({self.master_heartbeat_ms}) and <= 65535, "
                              f"got {self.master_heartbeat_timeout_ms!r}")
        for key, lo, hi in OPTION_RANGES:
            v = getattr(self, key)
            if not (isinstance(v, int) and not isinstance(v, bool) and lo <= v <= hi):
                raise ConfigError(f"{key} must be an integer {lo}..{hi}, got {v!r}")
        if self.scaling_source not in SCALING_SOURCES:
            raise ConfigError(f"scaling_source must be one of {SCALING_SOURCES}, got "
                              f"{self.scaling_source!r}")
        if not 0.0 <= self.scaling_tolerance < 1.0:
            raise ConfigError(f"scaling_tolerance must be in [0, 1), got {self.scaling_tolerance!r}")
        if not (math.isfinite(self.boot_wait) and self.boot_wait >= 0.0):
            raise ConfigError(f"boot_wait must be a number of seconds >= 0, got {self.boot_wait!r}")
        if self.heartbeat_timeout * 1000.0 <= self.heartbeat_producer_ms:
            raise ConfigError(f"heartbeat_timeout ({self.heartbeat_timeout} s) must exceed the "
                              f"producer time ({self.heartbeat_producer_ms} ms); use 2-4x of it")

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def current_limits(self) -> tuple[float, ...]:
        return tuple(j.current_limit for j in self.joints)


INTEGER_KEYS = frozenset({"heartbeat_producer_ms", "master_heartbeat_ms", "master_node_id", "feedback_every",
                          "master_heartbeat_timeout_ms", "missed_cycle_tolerance"} | {k for k, _, _ in OPTION_RANGES})


def _joint(i: int, data: Any) -> JointConfig:
    where = f"joints[{i}]"
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where} must be a mapping with name, node_id, family, current_limit, units")
    known = {"name", "node_id", "family", "current_limit", "units", "read_motor_data",
             "write_current_limit", "position_limits", "velocity_limit", "eds"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; known: {sorted(known)}")
    node_id = data.get("node_id", i + 1)
    if not isinstance(node_id, int) or isinstance(node_id, bool) or not 1 <= node_id <= 127:
        raise ConfigError(f"{where}.node_id must be an integer 1..127, got {node_id!r}")
    family = str(data.get("family", "epos4")).lower()
    if family not in FAMILIES:
        raise ConfigError(f"{where}.family must be one of {FAMILIES}, got {data.get('family')!r}")
    raw_limit: Any = data.get("current_limit")      # whatever the YAML holds
    try:
        limit = float(raw_limit)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}.current_limit must be a number of amperes, got {raw_limit!r}") from None
    if not math.isfinite(limit) or limit <= 0.0:
        raise ConfigError(f"{where}.current_limit must be finite and > 0 A, got {limit!r}")
    units_data = dict(data.get("units") or {})
    if "family" in units_data and str(units_data["family"]).lower() != family:
        raise ConfigError(f"{where}: units.family {units_data['family']!r} differs from family {family!r}")
    units_data["family"] = family
    try:
        units = DriveUnits.from_mapping(units_data)
    except UnitsError as exc:
        raise ConfigError(f"{where}.units: {exc}") from None
    pos = data.get("position_limits")
    if pos is not None:
        try:
            lo, hi = (float(x) for x in pos)
        except (TypeError, ValueError):
            raise ConfigError(f"{where}.position_limits must be [low, high] rad, got {pos!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ConfigError(f"{where}.position_limits must be finite with low < high, got {pos!r}")
        pos = (lo, hi)
    vel = data.get("velocity_limit")
    if vel is not None:
        try:
            vel = float(vel)
        except (TypeError, ValueError):
            raise ConfigError(f"{where}.velocity_limit must be a number of rad/s, got {vel!r}") from None
        if not (math.isfinite(vel) and vel > 0.0):
            raise ConfigError(f"{where}.velocity_limit must be finite and > 0 rad/s, got {vel!r}")
    eds = data.get("eds")
    if eds is not None:
        path = Path(str(eds)).expanduser()
        if not path.is_file():
            raise ConfigError(f"{where}.eds: no such file {str(path)!r} (the drive's EDS/DCF; leave it "
                              "out to use the built-in object dictionary)")
        eds = str(path)
    return JointConfig(name=str(data.get("name", f"joint{i + 1}")), node_id=node_id,
                       current_limit=limit, units=units,
                       read_motor_data=bool(data.get("read_motor_data", False)),
                       write_current_limit=bool(data.get("write_current_limit", True)),
                       position_limits=pos, velocity_limit=vel, eds=eds)


def config_from_mapping(data: Mapping[str, Any]) -> BridgeConfig:
    """Build and check a BridgeConfig from a parsed YAML mapping."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"bridge config must be a mapping, got {type(data).__name__}")
    top = {f.name for f in fields(BridgeConfig)}
    unknown = sorted(set(data) - top)
    if unknown:
        raise ConfigError(f"unknown key(s) {unknown}; known: {sorted(top)}")
    bus_data = data.get("bus")
    if not isinstance(bus_data, Mapping) or not bus_data.get("interface"):
        raise ConfigError("bus must be a mapping with at least 'interface' (socketcan, pcan, "
                          "kvaser, slcan, remote, virtual) and usually 'channel'")
    bus_data = dict(bus_data)
    extra = dict(bus_data.pop("kwargs", {}) or {})
    iface = str(bus_data.pop("interface"))
    channel = bus_data.pop("channel", None)
    bitrate = bus_data.pop("bitrate", 1_000_000)
    extra.update(bus_data)
    if iface == "udp_multicast":
        raise ConfigError("bus.interface 'udp_multicast' leaves this machine; use 'remote' with a "
                          "CAN hub on 127.0.0.1 (ff-can-hub) instead")
    try:
        bitrate = int(bitrate)
    except (TypeError, ValueError):
        raise ConfigError(f"bus.bitrate must be an integer bit/s, got {bitrate!r}") from None
    bus = BusConfig(interface=iface, channel=None if channel is None else str(channel),
                    bitrate=bitrate, kwargs=extra)
    joints_data = data.get("joints")
    if not isinstance(joints_data, Sequence) or isinstance(joints_data, (str, bytes)) or not joints_data:
        raise ConfigError("joints must be a non-empty list of joint mappings")
    joints = tuple(_joint(i, j) for i, j in enumerate(joints_data))
    kw: dict[str, Any] = {}
    for f in fields(BridgeConfig):
        if f.name in ("bus", "joints") or f.name not in data:
            continue
        v = data[f.name]
        if f.name in ("reset_communication", "check_identity", "player_process"):
            kw[f.name] = bool(v)
        elif f.name in ("scaling_source", "setpoint_timing", "sync_producer"):
            kw[f.name] = str(v).lower()
        elif f.name == "scheduler_rt_priority":
            if not isinstance(v, int) or isinstance(v, bool) or not -1 <= v <= 99:
                raise ConfigError("scheduler_rt_priority must be an integer -1..99 (0 = off, -1 = "
                                  f"auto), got {v!r}")
            kw[f.name] = v
        elif f.name in INTEGER_KEYS:
            if isinstance(v, float) and v.is_integer():
                v = int(v)
            kw[f.name] = v
        else:
            try:
                kw[f.name] = float(v)
            except (TypeError, ValueError):
                raise ConfigError(f"{f.name} must be a number, got {v!r}") from None
    return BridgeConfig(bus=bus, joints=joints, **kw)


def load_config(source: Union[str, Path, Mapping[str, Any]]) -> BridgeConfig:
    """A BridgeConfig from a YAML file path or an already parsed mapping."""
    if isinstance(source, Mapping):
        return config_from_mapping(source)

    path = Path(source)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"cannot read bridge config {path}: {exc}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path} is not valid YAML: {exc}") from None
    try:
        return config_from_mapping(data)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def with_bus(config: BridgeConfig, bus: Mapping[str, Any]) -> BridgeConfig:
    """A copy of ``config`` on another bus (e.g. a CAN hub URL given on the command line)."""

    data = dict(bus)
    iface = str(data.pop("interface"))
    channel = data.pop("channel", None)
    bitrate = int(data.pop("bitrate", config.bus.bitrate))
    return dataclasses.replace(config, bus=BusConfig(iface, channel, bitrate, data))

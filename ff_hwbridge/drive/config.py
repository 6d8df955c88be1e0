"""Bridge configuration: the CAN bus, the joints' drives, timing and safety limits (from YAML).

Example (``config/bridge_epos4_1dof.yaml``)::

    bus: {interface: socketcan, channel: can0, bitrate: 1000000}
    sync_period: 0.001            # s, SYNC producer period (TPDOs come on every SYNC)
    heartbeat_producer_ms: 10     # ms, written to each drive's 0x1017
    heartbeat_timeout: 0.04       # s, no heartbeat this long -> safe state
    master_heartbeat_ms: 0        # ms, > 0: the master produces a heartbeat (id master_node_id,
                                  #   default 127) and each drive consumes it (0x1016:01, timeout
                                  #   3x): if the bridge process dies, the drives stop by themselves
    setpoint_timeout: 0.5         # s, no fresh setpoint this long during a motion -> safe state
    spin_margin: 0.0003           # s, the setpoint scheduler sleeps until this long before a stamp
    scheduler_rt_priority: 0      # 1..99: SCHED_FIFO for the scheduler thread (needs CAP_SYS_NICE)
    feedback_timeout: 0.04        # s, no TPDO this long while SYNC runs -> safe state
                                  #    (default: max(heartbeat_timeout, 20 SYNC periods))
    joints:
      - name: joint1
        node_id: 1
        family: epos4
        current_limit: 10.0       # A, every command is clamped to this
        units: {nominal_current: 3.0, torque_constant: 0.0267, counts_per_rev: 2048, gear_ratio: 54}

Times are in s unless the name ends in ``_ms``; currents in A.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence, Union

import yaml

from ff_hwbridge.protocol.epos_od import CURRENT_MODE
from ff_hwbridge.protocol.units import FAMILIES, DriveUnits, UnitsError


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
                           (EPOS4 0x3001:01/:05, EPOS2 0x6410:01) instead of trusting the YAML.
    write_current_limit:   on configure, also write the drive's own output current limit
                           (EPOS4 0x3001:02, EPOS2 0x6410:02) = current_limit.
    """

    name: str
    node_id: int
    current_limit: float
    units: DriveUnits
    read_motor_data: bool = False
    write_current_limit: bool = True

    @property
    def family(self) -> str:
        return self.units.family

    @property
    def mode_of_operation(self) -> int:
        return MODE_OF_OPERATION[self.units.family]


@dataclass(frozen=True)
class BridgeConfig:
    """Everything the master needs. See the module docstring for the YAML form."""

    bus: BusConfig
    joints: tuple[JointConfig, ...]
    sync_period: float = 0.001
    heartbeat_producer_ms: int = 10
    master_heartbeat_ms: int = 0
    master_node_id: int = 127
    heartbeat_timeout: float = 0.1
    setpoint_timeout: float = 0.5
    feedback_timeout: float = 0.0
    sdo_timeout: float = 0.5
    boot_timeout: float = 2.0
    state_timeout: float = 1.0
    monitor_period: float = 0.002
    spin_margin: float = 0.0003
    scheduler_rt_priority: int = 0
    reset_communication: bool = True

    def __post_init__(self) -> None:
        if not self.joints:
            raise ConfigError("joints: at least one joint is needed")
        ids = [j.node_id for j in self.joints]
        if len(set(ids)) != len(ids):
            raise ConfigError(f"joints: node ids must differ, got {ids}")
        names = [j.name for j in self.joints]
        if len(set(names)) != len(names):
            raise ConfigError(f"joints: names must differ, got {names}")
        if self.feedback_timeout == 0.0:   # default: the heartbeat timeout, >= 20 SYNC periods
            object.__setattr__(self, "feedback_timeout",
                               max(float(self.heartbeat_timeout), 20.0 * float(self.sync_period)))
        for key in ("sync_period", "heartbeat_timeout", "setpoint_timeout", "feedback_timeout", "sdo_timeout",
                    "boot_timeout", "state_timeout", "monitor_period"):
            v = getattr(self, key)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"{key} must be a number of seconds > 0, got {v!r}")
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
        if self.heartbeat_timeout * 1000.0 <= self.heartbeat_producer_ms:
            raise ConfigError(f"heartbeat_timeout ({self.heartbeat_timeout} s) must exceed the "
                              f"producer time ({self.heartbeat_producer_ms} ms); use 2-4x of it")

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def current_limits(self) -> tuple[float, ...]:
        return tuple(j.current_limit for j in self.joints)


def _joint(i: int, data: Any) -> JointConfig:
    where = f"joints[{i}]"
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where} must be a mapping with name, node_id, family, current_limit, units")
    known = {"name", "node_id", "family", "current_limit", "units", "read_motor_data",
             "write_current_limit"}
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
    return JointConfig(name=str(data.get("name", f"joint{i + 1}")), node_id=node_id,
                       current_limit=limit, units=units,
                       read_motor_data=bool(data.get("read_motor_data", False)),
                       write_current_limit=bool(data.get("write_current_limit", True)))


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
        if f.name == "reset_communication":
            kw[f.name] = bool(v)
        elif f.name == "scheduler_rt_priority":
            if not isinstance(v, int) or isinstance(v, bool) or not 0 <= v <= 99:
                raise ConfigError(f"scheduler_rt_priority must be an integer 0..99 (0 = off), got {v!r}")
            kw[f.name] = v
        elif f.name in ("heartbeat_producer_ms", "master_heartbeat_ms", "master_node_id"):
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

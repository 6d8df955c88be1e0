"""One definition of the Maxon EPOS4 / EPOS2 objects the suite uses, built in code.

Written from the CiA 301/402 object definitions and maxon's documented object list (see docs/hardware.md);
no EDS is copied. ``OBJECTS`` is the single table (index, subindex, type, access, default, unit,
PDO-mappable) that both sides build from: the master (``epos.py``) for its RemoteNodes
(``build_object_dictionary(family, node_id)``: the contract's objects), the simulated drive
(``sim_epos.py``) for its LocalNode (``drive=True`` adds what only a drive serves: identity,
error history, RxPDO 2-4 / TxPDO 3-4, quick stop option, further motor data). Motor data
defaults come from ``MotorData`` (what a drive serves), e.g. ``MotorData.from_units(units)``.

Contract objects: 0x1000 device type, 0x1001 error register, 0x1016:01-02 consumer heartbeat
time ((node id << 16) | ms), 0x1017 producer heartbeat (ms), 0x1400/0x1600 RPDO1,
0x1800/0x1A00 TPDO1, 0x1801/0x1A01 TPDO2, 0x6040 controlword, 0x6041 statusword, 0x6060/0x6061
modes of operation (+display), 0x6064 position actual (inc), 0x606C velocity actual (rpm),
0x1003 pre-defined error field (error history, newest first), 0x1018 identity (:01 vendor id),
0x1029:01 communication error behaviour, 0x6007 abort connection option, 0x603F error code,
0x605A quick stop option, 0x605E fault reaction option, 0x6085 quick stop deceleration (rpm/s),
0x6084 profile deceleration (rpm/s, the "slow down ramp"; drive only),
0x60A9 SI unit velocity, 0x60C2 interpolation time period (:01 value, :02 index), 0x6502
supported drive modes, 0x3000:05 main sensor resolution (EPOS4, increments/rev), RxPDO1 event
timer 0x1400:05 (ms, deadline monitoring; master's view only: maxon's EPOS4 EDS lacks it),
0x6076 motor rated torque (µNm), 0x6071 target torque (per mille), 0x6077 torque actual (per
mille), 0x3001 motor data (EPOS4, :01 nominal current mA, :02 output current limit mA, :05 torque
constant µNm/A), 0x30D1 current actual values (EPOS4, :01 averaged, :02 actual, mA), 0x2030
current mode setting value (EPOS2, mA), 0x6078 current actual (EPOS2, mA), 0x6410 motor data
(EPOS2, :01 continuous current limit mA, :02 output current limit mA). Units: see ``units.py``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional, Union

from canopen.objectdictionary import (INTEGER8, INTEGER16, INTEGER32, UNSIGNED8, UNSIGNED16, UNSIGNED32,
                                      VISIBLE_STRING, ObjectDictionary, ODArray, ODRecord, ODVariable)

from ff_hwbridge.protocol.units import FAMILIES, DriveUnits

# RPDO/TPDO numbers used (1-based, canopen's pdo map keys)
RPDO_SETPOINT = 1
TPDO_STATUS = 1
TPDO_MOTION = 2

#: 0x6060 modes of operation value of the contract's current mode: EPOS4 CST, EPOS2 current mode
CURRENT_MODE = {"epos4": 10, "epos2": -3}
MAXON_VENDOR_ID = 0x000000FB
#: 0x1000 device type: low 16 bits = device profile number (402 = drives and motion control)
DEVICE_PROFILE_402 = 402
#: 0x60A9 SI unit velocity of the suite's conversions: motor rpm (maxon's default; CiA 402
#: notation prefix 0x00, unit 0xB4 = revolutions, time 0x47 = minute)
VELOCITY_UNIT_RPM = 0x00B44700
#: 0x6502 supported drive modes (CiA 402 bits: 0 PPM, 2 PVM, 5 HMM, 7 CSP, 8 CSV, 9 CST)
SUPPORTED_MODES = {"epos4": (1 << 0) | (1 << 2) | (1 << 5) | (1 << 7) | (1 << 8) | (1 << 9),
                   "epos2": (1 << 0) | (1 << 2) | (1 << 5) | (1 << 6)}
PDO_VALID_BIT = 1 << 31          # set = PDO disabled (CiA 301 "not valid")
PDO_NO_RTR_BIT = 1 << 30         # set = no RTR allowed on this TxPDO (maxon's default on TxPDOs)
#: 0x605A quick stop option code at maxon's factory setting: 6 = quick-stop ramp, then stay in
#: QUICK STOP ACTIVE
FACTORY_QUICK_STOP_OPTION = 6


@dataclass(frozen=True)
class MotorData:
    """Motor data a drive serves, raw object values: mA, µNm/A (0x3001:05), µNm (0x6076)."""

    nominal_current_ma: int = 0
    output_current_limit_ma: int = 10000
    torque_constant_raw: int = 0
    rated_torque_raw: int = 0
    encoder_resolution: int = 0           # increments per motor revolution (EPOS4 0x3000:05)

    @classmethod
    def from_units(cls, units: DriveUnits, output_current_limit_ma: int = 10000) -> "MotorData":
        """The objects of ``units`` (nominal current, kt, rated torque = kt x I_nominal,
        encoder increments per revolution)."""
        return cls(units.nominal_current_ma, int(output_current_limit_ma),
                   units.torque_constant_raw, units.rated_torque_raw,
                   int(round(units.counts_per_rev)))


@dataclass(frozen=True)
class _Ctx:
    """What object defaults may depend on."""

    family: str
    node_id: int
    motor: MotorData
    quick_stop_option: int
    device_name: str


Default = Union[int, str, Callable[[_Ctx], Union[int, str]]]


@dataclass(frozen=True)
class Entry:
    """One (sub)object: subindex, name, CANopen data type, access, default, unit, PDO-mappable.

    ``drive_only`` entries are served by a drive but not needed in the master's view;
    ``master_only`` entries are in the master's view (written where a drive has them, optional)
    but not served by the simulated drive, because maxon's EPOS4 EDS does not list them."""

    sub: int
    name: str
    dtype: int
    access: str = "rw"
    default: Default = 0
    unit: str = ""
    pdo: bool = False
    drive_only: bool = False
    master_only: bool = False


@dataclass(frozen=True)
class ObjectSpec:
    """One object: a variable (one Entry, sub 0), a record or an array (sub 0 added as the
    highest sub-index). ``families``: the drive families that have it."""

    index: int
    name: str
    entries: tuple[Entry, ...]
    kind: str = "var"                     # 'var' | 'record' | 'array'
    families: tuple[str, ...] = FAMILIES
    drive_only: bool = False
    sub0: Optional[Entry] = None          # default: highest sub-index (ro)


def _v(index: int, name: str, dtype: int, access: str = "rw", default: Default = 0,
       unit: str = "", pdo: bool = False, families: tuple[str, ...] = FAMILIES,
       drive_only: bool = False) -> ObjectSpec:
    return ObjectSpec(index, name, (Entry(0, name, dtype, access, default, unit, pdo),), "var",
                      families, drive_only)


def _pdo_objects() -> list[ObjectSpec]:
    """RxPDO / TxPDO 1-4 communication and mapping objects (the contract uses RxPDO1 and
    TxPDO1/2; the rest are drive-only). Defaults per maxon: RxPDO1 = controlword on 0x200+id,
    TxPDO1 = statusword on 0x180+id (inhibit time 1 ms), the others disabled (COB-ID bit 31) and
    empty; TxPDO COB-IDs with bit 30 (no RTR) set."""
    out = []
    for n in range(4):
        bit = 0 if n == 0 else PDO_VALID_BIT

        def rcob(c: _Ctx, n: int = n, bit: int = bit) -> int:
            return (0x200 + 0x100 * n + c.node_id) | bit

        def tcob(c: _Ctx, n: int = n, bit: int = bit) -> int:
            return (0x180 + 0x100 * n + c.node_id) | bit | PDO_NO_RTR_BIT

        entries = [Entry(i, f"Mapped object {i}", UNSIGNED32, "rw", 0) for i in range(1, 9)]
        rmap = [Entry(1, "Mapped object 1", UNSIGNED32, "rw", 0x60400010)] if n == 0 else []
        tmap = [Entry(1, "Mapped object 1", UNSIGNED32, "rw", 0x60410010)] if n == 0 else []
        rx_only, tx_only = n > 0, n > 1
        out += [
            ObjectSpec(0x1400 + n, f"Receive PDO {n + 1} parameter", (
                Entry(1, "COB-ID used by RxPDO", UNSIGNED32, "rw", rcob),
                Entry(2, "Transmission type", UNSIGNED8, "rw", 255),
                # CiA 301 RPDO deadline monitoring; not in maxon's EPOS4 EDS
                Entry(5, "Event timer", UNSIGNED16, "rw", 0, "ms", master_only=True)), "record",
                drive_only=rx_only),
            ObjectSpec(0x1600 + n, f"Receive PDO {n + 1} mapping",
                       tuple(rmap + entries[len(rmap):]), "record", drive_only=rx_only),
            ObjectSpec(0x1800 + n, f"Transmit PDO {n + 1} parameter", (
                Entry(1, "COB-ID used by TxPDO", UNSIGNED32, "rw", tcob),
                Entry(2, "Transmission type", UNSIGNED8, "rw", 255),
                Entry(3, "Inhibit time", UNSIGNED16, "rw", 10 if n == 0 else 0, "100 µs"),
                Entry(5, "Event timer", UNSIGNED16, "rw", 0, "ms")), "record",
                drive_only=tx_only),
            ObjectSpec(0x1A00 + n, f"Transmit PDO {n + 1} mapping",
                       tuple(tmap + entries[len(tmap):]), "record", drive_only=tx_only),
        ]
    return out


E4, E2 = ("epos4",), ("epos2",)
U8, U16, U32, I8, I16, I32 = UNSIGNED8, UNSIGNED16, UNSIGNED32, INTEGER8, INTEGER16, INTEGER32

#: The EPOS objects, communication profile first. Defaults that depend on the drive are callables.
OBJECTS: tuple[ObjectSpec, ...] = (
    _v(0x1000, "Device type", U32, "ro", 0x00020192),
    _v(0x1001, "Error register", U8, "ro", 0, pdo=True),
    ObjectSpec(0x1003, "Pre-defined error field",
               tuple(Entry(i, f"Standard error field {i}", U32, "ro", 0) for i in range(1, 9)),
               "array", sub0=Entry(0, "Highest sub-index supported", U8, "rw", 0)),
    _v(0x1005, "COB-ID SYNC", U32, "rw", 0x80, drive_only=True),
    _v(0x1008, "Manufacturer device name", VISIBLE_STRING, "const", lambda c: c.device_name,
       drive_only=True),
    _v(0x1014, "COB-ID EMCY", U32, "rw", lambda c: 0x80 + c.node_id, drive_only=True),
    ObjectSpec(0x1016, "Consumer heartbeat time",       # (node id << 16) | time ms
               tuple(Entry(i, f"Consumer heartbeat time {i}", U32, "rw", 0, "(id << 16) | ms")
                     for i in range(1, 3)), "array"),      # an EPOS4 has two entries
    _v(0x1017, "Producer heartbeat time", U16, "rw", 0, "ms"),
    ObjectSpec(0x1029, "Error behaviour", (         # CiA 301: 0 pre-operational, 1 none, 2 stopped
        Entry(1, "Communication error", U8, "rw", 0),), "array"),
    ObjectSpec(0x1018, "Identity object", (
        Entry(1, "Vendor-ID", U32, "ro", MAXON_VENDOR_ID),
        Entry(2, "Product code", U32, "ro",
              lambda c: 0x6050_0000 if c.family == "epos4" else 0x2000_0000),
        Entry(3, "Revision number", U32, "ro", 0x0001_0000),
        Entry(4, "Serial number", U32, "ro", lambda c: 0x5100_0000 + c.node_id)), "record"),
    *_pdo_objects(),
    _v(0x6040, "Controlword", U16, "rw", 0, pdo=True),
    _v(0x6041, "Statusword", U16, "ro", 0, pdo=True),
    _v(0x6007, "Abort connection option code", I16, "rw", 3),   # maxon default 3 = quick stop
    _v(0x603F, "Error code", U16, "ro", 0, pdo=True),
    _v(0x605A, "Quick stop option code", I16, "rw", lambda c: c.quick_stop_option),
    _v(0x605E, "Fault reaction option code", I16, "rw", 2),      # 2 = quick stop ramp
    _v(0x6084, "Profile deceleration", U32, "rw", 10000, "rpm/s", drive_only=True),
    _v(0x6085, "Quick stop deceleration", U32, "rw", 10000, "rpm/s"),
    _v(0x60A9, "SI unit velocity", U32, "rw", VELOCITY_UNIT_RPM),
    ObjectSpec(0x60C2, "Interpolation time period", (
        Entry(1, "Interpolation time period value", U8, "rw", 0),
        Entry(2, "Interpolation time index", I8, "rw", -3, "10^index s")), "record"),
    _v(0x6502, "Supported drive modes", U32, "ro", lambda c: SUPPORTED_MODES[c.family]),
    _v(0x6060, "Modes of operation", I8, "rw", 0, pdo=True),
    _v(0x6061, "Modes of operation display", I8, "ro", 0, pdo=True),
    _v(0x6064, "Position actual value", I32, "ro", 0, "increments (motor encoder)", pdo=True),
    _v(0x606C, "Velocity actual value", I32, "ro", 0, "rpm (motor)", pdo=True),
    # EPOS4: cyclic synchronous torque
    _v(0x6071, "Target torque", I16, "rw", 0, "per mille of 0x6076", pdo=True, families=E4),
    _v(0x6076, "Motor rated torque", U32, "rw", lambda c: c.motor.rated_torque_raw, "µNm",
       families=E4),
    _v(0x6077, "Torque actual value", I16, "ro", 0, "per mille of 0x6076", pdo=True,
       families=E4),
    ObjectSpec(0x3000, "Axis configuration", (
        Entry(1, "Sensors configuration", U32, "rw", 0, drive_only=True),
        Entry(2, "Control structure", U32, "rw", 0, drive_only=True),
        Entry(3, "Commutation sensors", U32, "rw", 0, drive_only=True),
        Entry(4, "Axis configuration miscellaneous", U32, "rw", 0, drive_only=True),
        Entry(5, "Main sensor resolution", U32, "rw", lambda c: c.motor.encoder_resolution,
              "increments/rev")), "record", families=E4),
    ObjectSpec(0x3001, "Motor data", (
        Entry(1, "Nominal current", U32, "rw", lambda c: c.motor.nominal_current_ma, "mA"),
        Entry(2, "Output current limit", U32, "rw",
              lambda c: c.motor.output_current_limit_ma, "mA"),
        Entry(3, "Number of pole pairs", U8, "rw", 1, drive_only=True),
        Entry(4, "Thermal time constant winding", U16, "rw", 400, "0.1 s", drive_only=True),
        Entry(5, "Torque constant", U32, "rw", lambda c: c.motor.torque_constant_raw, "µNm/A")),
        "record", families=E4),
    ObjectSpec(0x30D1, "Current actual values", (
        Entry(1, "Current actual value averaged", I32, "ro", 0, "mA", pdo=True),
        Entry(2, "Current actual value", I32, "ro", 0, "mA", pdo=True)), "record", families=E4),
    # EPOS2: current mode
    _v(0x2030, "Current mode setting value", I16, "rw", 0, "mA", pdo=True, families=E2),
    _v(0x2027, "Current actual value averaged", I16, "ro", 0, "mA", pdo=True, families=E2,
       drive_only=True),
    _v(0x6078, "Current actual value", I16, "ro", 0, "mA", pdo=True, families=E2),
    ObjectSpec(0x6410, "Motor data", (
        Entry(1, "Continuous current limit", U16, "rw", lambda c: c.motor.nominal_current_ma, "mA"),
        Entry(2, "Output current limit", U16, "rw", lambda c: c.motor.output_current_limit_ma,
              "mA"),
        Entry(3, "Pole pair number", U8, "rw", 1, drive_only=True),
        Entry(4, "Maximal speed in current mode", U32, "rw", 25000, "rpm", drive_only=True),
        Entry(5, "Thermal time constant winding", U16, "rw", 400, "0.1 s", drive_only=True)),
        "record", families=E2),
)


def _variable(index: int, e: Entry, ctx: _Ctx) -> ODVariable:
    v = ODVariable(e.name, index, e.sub)
    v.data_type, v.access_type, v.pdo_mappable = e.dtype, e.access, e.pdo
    # canopen annotates ``default`` as int; VISIBLE_STRING objects take a str default
    v.default = e.default(ctx) if callable(e.default) else e.default  # type: ignore[assignment]
    v.unit = e.unit
    return v


def build_object_dictionary(family: str = "epos4", node_id: int = 1,
                            units: Optional[DriveUnits] = None,
                            output_current_limit_ma: int = 10000, *,
                            motor: Optional[MotorData] = None, drive: bool = False,
                            quick_stop_option: int = FACTORY_QUICK_STOP_OPTION,
                            device_name: Optional[str] = None) -> ObjectDictionary:
    """The object dictionary of one drive of ``family`` ('epos4' | 'epos2'), from ``OBJECTS``.

    ``drive=False``: the master's view (the contract's objects); ``drive=True``: also what only
    a drive serves. Motor data defaults from ``motor`` (raw values), else from ``units`` (with
    ``output_current_limit_ma``), else 0 (limit: ``output_current_limit_ma``).
    """
    fam = str(family).lower()
    if fam not in FAMILIES:
        raise ValueError(f"family must be 'epos4' or 'epos2', got {family!r}")
    if motor is None:
        motor = (MotorData.from_units(units, output_current_limit_ma) if units is not None
                 else MotorData(output_current_limit_ma=int(output_current_limit_ma)))
    ctx = _Ctx(fam, int(node_id), motor, int(quick_stop_option),
               device_name if device_name is not None else f"{fam.upper()}")
    od = ObjectDictionary()
    od.node_id = node_id
    for spec in OBJECTS:
        if fam not in spec.families or (spec.drive_only and not drive):
            continue
        entries = [e for e in spec.entries
                   if (drive or not e.drive_only) and not (drive and e.master_only)]
        if spec.kind == "var":
            od.add_object(_variable(spec.index, entries[0], ctx))
            continue
        obj = ODArray(spec.name, spec.index) if spec.kind == "array" else ODRecord(spec.name, spec.index)
        # sub 0: highest sub-index (for PDO mapping objects: the number of mapped objects)
        mapping = 0x1600 <= spec.index <= 0x17FF or 0x1A00 <= spec.index <= 0x1BFF
        if spec.sub0 is not None:
            sub0 = spec.sub0
        elif mapping:
            n = sum(1 for e in entries if e.default)
            sub0 = Entry(0, "Highest sub-index supported", U8, "rw", n)
        else:
            sub0 = Entry(0, "Highest sub-index supported", U8, "ro", max(e.sub for e in entries))
        obj.add_member(_variable(spec.index, sub0, ctx))
        for e in entries:
            obj.add_member(_variable(spec.index, e, ctx))
        od.add_object(obj)
    return od


# The PDO layout of the contract: (index, subindex, struct format) per mapped object, in order.
def rpdo_layout(family: str) -> list[tuple[int, int, str]]:
    """RPDO1: controlword (u16) + setpoint (EPOS4 0x6071 i16 per mille, EPOS2 0x2030 i16 mA)."""
    return [(0x6040, 0, "H"), (0x6071, 0, "h") if family == "epos4" else (0x2030, 0, "h")]


def tpdo1_layout(family: str) -> list[tuple[int, int, str]]:
    """TPDO1 (on every SYNC): statusword (u16) + position actual (i32, increments)."""
    return [(0x6041, 0, "H"), (0x6064, 0, "i")]


def tpdo2_layout(family: str) -> list[tuple[int, int, str]]:
    """TPDO2 (on every SYNC): velocity actual (i32, rpm) + current actual (EPOS4 0x30D1:02 i32
    mA, EPOS2 0x6078 i16 mA)."""
    return [(0x606C, 0, "i"), (0x30D1, 2, "i") if family == "epos4" else (0x6078, 0, "h")]


def struct_format(layout: list[tuple[int, int, str]]) -> str:
    """The little-endian struct format of a PDO layout."""
    return "<" + "".join(f for _, _, f in layout)

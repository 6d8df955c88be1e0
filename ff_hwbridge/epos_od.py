"""The part of a Maxon EPOS4 / EPOS2 object dictionary the suite uses, built in code.

Written from the CiA 301/402 object definitions and maxon's documented object list (DESIGN.md);
no EDS is copied. The master (``epos.py``) uses it for its RemoteNodes; a simulated drive can use
it for a LocalNode (``build_object_dictionary(family, units=...)`` fills the motor data).

Objects: 0x1000 device type, 0x1001 error register, 0x1016:01 consumer heartbeat time
((node id << 16) | ms), 0x1017 producer heartbeat (ms),
0x1400/0x1600 RPDO1, 0x1800/0x1A00 TPDO1, 0x1801/0x1A01 TPDO2, 0x6040 controlword,
0x6041 statusword, 0x6060/0x6061 modes of operation (+display), 0x6064 position actual (inc),
0x606C velocity actual (rpm), 0x6076 motor rated torque (µNm), 0x6071 target torque (per mille),
0x6077 torque actual (per mille), 0x3001 motor data (EPOS4, :01 nominal current mA, :02 output
current limit mA, :05 torque constant µNm/A), 0x30D1 current actual values (EPOS4, :01 averaged,
:02 actual, mA), 0x2030 current mode setting value (EPOS2, mA), 0x6078 current actual (EPOS2, mA),
0x6410 motor data (EPOS2, :01 continuous current limit mA, :02 output current limit mA).
"""
from __future__ import annotations

from typing import Optional

from canopen.objectdictionary import (INTEGER8, INTEGER16, INTEGER32, UNSIGNED8, UNSIGNED16,
                                      UNSIGNED32, ObjectDictionary, ODRecord, ODVariable)

from .units import DriveUnits

# RPDO/TPDO numbers used (1-based, canopen's pdo map keys)
RPDO_SETPOINT = 1
TPDO_STATUS = 1
TPDO_MOTION = 2


def _var(name: str, index: int, subindex: int, dtype: int, access: str = "rw",
         default: int = 0, pdo: bool = False) -> ODVariable:
    v = ODVariable(name, index, subindex)
    v.data_type = dtype
    v.access_type = access
    v.default = default
    v.pdo_mappable = pdo
    return v


def _record(od: ObjectDictionary, name: str, index: int,
            entries: list[tuple[int, str, int, str, int]]) -> ODRecord:
    rec = ODRecord(name, index)
    rec.add_member(_var("Highest sub-index supported", index, 0, UNSIGNED8, "ro",
                        max(e[0] for e in entries)))
    for sub, sname, dtype, access, default in entries:
        rec.add_member(_var(sname, index, sub, dtype, access, default))
    od.add_object(rec)
    return rec


def _pdo_comm(od: ObjectDictionary, name: str, index: int, cob_id: int, trans_type: int) -> None:
    _record(od, name, index, [
        (1, "COB-ID", UNSIGNED32, "rw", cob_id),
        (2, "Transmission type", UNSIGNED8, "rw", trans_type),
        (3, "Inhibit time", UNSIGNED16, "rw", 0),
        (5, "Event timer", UNSIGNED16, "rw", 0),
    ])


def _pdo_map(od: ObjectDictionary, name: str, index: int, defaults: list[int]) -> None:
    rec = ODRecord(name, index)
    rec.add_member(_var("Number of mapped objects", index, 0, UNSIGNED8, "rw", len(defaults)))
    for sub in range(1, 9):
        rec.add_member(_var(f"Mapping entry {sub}", index, sub, UNSIGNED32, "rw",
                            defaults[sub - 1] if sub <= len(defaults) else 0))
    od.add_object(rec)


def build_object_dictionary(family: str = "epos4", node_id: int = 1,
                            units: Optional[DriveUnits] = None,
                            output_current_limit_ma: int = 10000) -> ObjectDictionary:
    """The objects the suite uses for one drive of ``family`` ('epos4' | 'epos2').

    ``units`` (DriveUnits) fills the motor data defaults (what a simulated drive serves);
    without it the motor data objects default to 0. PDO defaults follow maxon's (RxPDO1 =
    controlword on 0x200+id, TxPDO1 = statusword on 0x180+id); the master remaps them.
    """
    fam = family.lower()
    if fam not in ("epos4", "epos2"):
        raise ValueError(f"family must be 'epos4' or 'epos2', got {family!r}")
    od = ObjectDictionary()
    od.node_id = node_id
    od.add_object(_var("Device type", 0x1000, 0, UNSIGNED32, "ro", 0x00020192))
    od.add_object(_var("Error register", 0x1001, 0, UNSIGNED8, "ro", 0))
    od.add_object(_var("Producer heartbeat time", 0x1017, 0, UNSIGNED16, "rw", 0))
    _record(od, "Consumer heartbeat time", 0x1016, [
        (1, "Consumer heartbeat time 1", UNSIGNED32, "rw", 0),    # (node id << 16) | time ms
    ])
    _pdo_comm(od, "Receive PDO 1 parameter", 0x1400, 0x200 + node_id, 255)
    _pdo_map(od, "Receive PDO 1 mapping", 0x1600, [0x60400010])
    _pdo_comm(od, "Transmit PDO 1 parameter", 0x1800, 0x180 + node_id, 255)
    _pdo_map(od, "Transmit PDO 1 mapping", 0x1A00, [0x60410010])
    _pdo_comm(od, "Transmit PDO 2 parameter", 0x1801, 0x280 + node_id, 255)
    _pdo_map(od, "Transmit PDO 2 mapping", 0x1A01, [])
    od.add_object(_var("Controlword", 0x6040, 0, UNSIGNED16, "rw", 0, pdo=True))
    od.add_object(_var("Statusword", 0x6041, 0, UNSIGNED16, "ro", 0, pdo=True))
    od.add_object(_var("Modes of operation", 0x6060, 0, INTEGER8, "rw", 0, pdo=True))
    od.add_object(_var("Modes of operation display", 0x6061, 0, INTEGER8, "ro", 0, pdo=True))
    od.add_object(_var("Position actual value", 0x6064, 0, INTEGER32, "ro", 0, pdo=True))
    od.add_object(_var("Velocity actual value", 0x606C, 0, INTEGER32, "ro", 0, pdo=True))
    nominal_ma = units.nominal_current_ma if units else 0
    if fam == "epos4":
        od.add_object(_var("Target torque", 0x6071, 0, INTEGER16, "rw", 0, pdo=True))
        od.add_object(_var("Torque actual value", 0x6077, 0, INTEGER16, "ro", 0, pdo=True))
        od.add_object(_var("Motor rated torque", 0x6076, 0, UNSIGNED32, "rw",
                           units.rated_torque_raw if units else 0))
        _record(od, "Motor data", 0x3001, [
            (1, "Nominal current", UNSIGNED32, "rw", nominal_ma),
            (2, "Output current limit", UNSIGNED32, "rw", int(output_current_limit_ma)),
            (5, "Torque constant", UNSIGNED32, "rw", units.torque_constant_raw if units else 0),
        ])
        rec = ODRecord("Current actual values", 0x30D1)
        rec.add_member(_var("Highest sub-index supported", 0x30D1, 0, UNSIGNED8, "ro", 2))
        rec.add_member(_var("Current actual value averaged", 0x30D1, 1, INTEGER32, "ro", 0, pdo=True))
        rec.add_member(_var("Current actual value", 0x30D1, 2, INTEGER32, "ro", 0, pdo=True))
        od.add_object(rec)
    else:
        od.add_object(_var("Current mode setting value", 0x2030, 0, INTEGER16, "rw", 0, pdo=True))
        od.add_object(_var("Current actual value", 0x6078, 0, INTEGER16, "ro", 0, pdo=True))
        _record(od, "Motor data", 0x6410, [
            (1, "Continuous current limit", UNSIGNED16, "rw", nominal_ma),
            (2, "Output current limit", UNSIGNED16, "rw", int(output_current_limit_ma)),
        ])
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

"""CANopen / CiA 402 / Maxon EPOS numbers: the drive state machine (``cia402``), the object
dictionary and PDO layouts (``epos_od``) and the unit conversions A ↔ ‰ / mA, rad ↔ increments,
rad/s ↔ rpm (``units``)."""
from ff_hwbridge.protocol.cia402 import (CONTROLWORD, Command, State, StatuswordError, Transition,
                                         TransitionError, apply_command, decode_controlword,
                                         decode_statusword, encode_statusword, next_controlword)
from ff_hwbridge.protocol.epos_od import (CURRENT_MODE, MotorData, build_object_dictionary, rpdo_layout,
                                          struct_format, tpdo1_layout, tpdo2_layout)
from ff_hwbridge.protocol.units import FAMILIES, DriveUnits, UnitsError

__all__ = [
    "CONTROLWORD", "CURRENT_MODE", "FAMILIES", "Command", "DriveUnits", "MotorData", "State",
    "StatuswordError", "Transition", "TransitionError", "UnitsError", "apply_command",
    "build_object_dictionary", "decode_controlword", "decode_statusword", "encode_statusword",
    "next_controlword", "rpdo_layout", "struct_format", "tpdo1_layout", "tpdo2_layout",
]

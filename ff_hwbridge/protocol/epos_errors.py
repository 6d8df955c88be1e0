"""EMCY / error codes of the Maxon EPOS4 and EPOS2 (0x603F, 0x1003, EMCY frames): code -> text,
and whether the code is a warning (the drive keeps running) or an error (the drive is in Fault).

Sources (see docs/hardware.md): the CiA 301 / CiA 402 emergency code classes; maxon's EPOS4
Firmware Specification, chapter "Error handling" (device error codes; the list below is the part
of it that public drivers carry: 0x1000 ... 0x8611); the warning code 0xFF01 as an EPOS4 sends it
(a warning: bit 7 of the statusword, no Fault). Codes the table does not know are decoded by
their CiA class and treated as errors (the safe side).

Pure data and functions, no dependencies.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["EMCY_CLASSES", "ERRORS", "WARNINGS", "ErrorInfo", "describe", "is_warning"]


@dataclass(frozen=True)
class ErrorInfo:
    """One decoded code: ``text`` for people, ``warning`` True when the drive keeps operating."""

    code: int
    text: str
    warning: bool

    def __str__(self) -> str:
        if self.code == 0:
            return "0x0000 no error"
        kind = "warning" if self.warning else "error"
        return f"0x{self.code:04X} {self.text} ({kind})"


#: CiA 301 / 402 emergency code classes (high byte, or high nibble << 4): readable fallbacks
EMCY_CLASSES: dict[int, str] = {
    0x00: "error reset / no error", 0x10: "generic error", 0x20: "current",
    0x21: "current, device input side", 0x22: "current inside the device",
    0x23: "current, device output side", 0x30: "voltage", 0x31: "mains voltage",
    0x32: "voltage inside the device", 0x33: "output voltage", 0x40: "temperature",
    0x41: "ambient temperature", 0x42: "device temperature", 0x50: "device hardware",
    0x60: "device software", 0x61: "internal software", 0x62: "user software",
    0x63: "data set", 0x70: "additional modules", 0x73: "sensor",
    0x80: "monitoring", 0x81: "communication", 0x82: "protocol error",
    0x84: "velocity / following", 0x86: "position", 0x8A: "control",
    0x90: "external error", 0xF0: "additional functions", 0xFF: "device specific"}

#: EPOS errors (the drive enters Fault), per maxon's firmware specification and CiA 301
ERRORS: dict[int, str] = {
    0x1000: "generic error",
    0x2310: "over current",
    0x3210: "over voltage",
    0x3220: "under voltage",
    0x4210: "over temperature",
    0x5113: "supply voltage (+5 V) too low",
    0x5114: "supply voltage output stage too low",
    0x6100: "internal software error",
    0x6320: "software parameter error",
    0x7320: "position sensor error",
    0x8110: "CAN overrun (object lost)",
    0x8111: "CAN overrun",
    0x8120: "CAN passive mode",
    0x8130: "CAN heartbeat error (a consumed heartbeat, e.g. the master's, timed out)",
    0x8150: "CAN PDO COB-ID collision",
    0x81FD: "CAN bus off",
    0x81FE: "CAN Rx queue overflow",
    0x81FF: "CAN Tx queue overflow",
    0x8210: "CAN PDO length error",
    0x8250: ("RPDO timeout (interpolation aborted in a cyclic synchronous mode: no RxPDO within "
             "the interpolation time period 0x60C2; a hung master or a setpoint not sent every "
             "SYNC cycle)"),
    0x8611: "following error",
}

#: EPOS warnings (statusword bit 7; the drive stays in its state)
WARNINGS: dict[int, str] = {
    0xFF01: "device warning (see the drive's warning details in EPOS Studio)",
}


def is_warning(code: int) -> bool:
    """True for a warning code (the drive keeps operating), False for an error or unknown code."""
    return int(code) & 0xFFFF in WARNINGS


def describe(code: int) -> ErrorInfo:
    """The text and kind of an EMCY / 0x603F / 0x1003 code (low 16 bits are used)."""
    c = int(code) & 0xFFFF
    if c == 0:
        return ErrorInfo(0, "no error", False)
    if c in WARNINGS:
        return ErrorInfo(c, WARNINGS[c], True)
    if c in ERRORS:
        return ErrorInfo(c, ERRORS[c], False)
    cls = EMCY_CLASSES.get(c >> 8, EMCY_CLASSES.get((c >> 12) << 4, "unknown error"))
    return ErrorInfo(c, cls, False)

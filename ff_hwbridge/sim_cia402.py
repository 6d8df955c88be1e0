"""The DRIVE side of the CiA 402 state machine, as the simulated EPOS runs it.

The master side (decoding statuswords, choosing controlwords) lives in ``ff_hwbridge.cia402``;
this module is what a drive does with a controlword: which transition (numbered as in
CiA 402 / IEC 61800-7-201, figure "state machine") fires and which statusword it then shows.

Statusword bits produced (standard meaning): 0 ready to switch on, 1 switched on, 2 operation
enabled, 3 fault, 4 voltage enabled, 5 quick stop (0 = active), 6 switch on disabled, 7 warning,
9 remote, 12 "drive follows the command value" (cyclic synchronous modes, operation enabled).
Values: SOD 0x0240, RTSO 0x0221, SO 0x0223, OE 0x0237 (0x1237 when following a CST/current
setpoint), QSA 0x0217, FRA 0x021F, FAULT 0x0208. A master must decode them with the standard masks.
"""
from __future__ import annotations

import enum
from typing import Optional


class DriveState(enum.Enum):
    """CiA 402 power drive system states."""

    NOT_READY_TO_SWITCH_ON = "not ready to switch on"
    SWITCH_ON_DISABLED = "switch on disabled"
    READY_TO_SWITCH_ON = "ready to switch on"
    SWITCHED_ON = "switched on"
    OPERATION_ENABLED = "operation enabled"
    QUICK_STOP_ACTIVE = "quick stop active"
    FAULT_REACTION_ACTIVE = "fault reaction active"
    FAULT = "fault"


S = DriveState

#: Statusword bits 0-6 per state (bit 4 "voltage enabled" set where the power stage is on).
_STATUS_BITS: dict[DriveState, int] = {
    S.NOT_READY_TO_SWITCH_ON: 0x0000,
    S.SWITCH_ON_DISABLED: 0x0040,
    S.READY_TO_SWITCH_ON: 0x0021,
    S.SWITCHED_ON: 0x0023,
    S.OPERATION_ENABLED: 0x0037,
    S.QUICK_STOP_ACTIVE: 0x0017,
    S.FAULT_REACTION_ACTIVE: 0x001F,
    S.FAULT: 0x0008,
}
SW_WARNING = 1 << 7
SW_REMOTE = 1 << 9
SW_FOLLOWS_COMMAND = 1 << 12
CW_FAULT_RESET = 1 << 7

#: States in which the power stage drives current (others apply 0 A).
POWERED = frozenset({S.OPERATION_ENABLED})


def statusword(state: DriveState, *, follows_command: bool = False, warning: bool = False) -> int:
    """The statusword (u16) a drive in ``state`` reports."""
    sw = _STATUS_BITS[state]
    if state is not S.NOT_READY_TO_SWITCH_ON:
        sw |= SW_REMOTE
    if follows_command and state is S.OPERATION_ENABLED:
        sw |= SW_FOLLOWS_COMMAND
    if warning:
        sw |= SW_WARNING
    return sw


def command_of(controlword: int) -> str:
    """Name the device-control command in a controlword (bits 0-3, 7), per CiA 402 table."""
    cw = controlword & 0x8F
    if cw & 0x02 == 0:                      # bit 1 enable voltage = 0
        return "disable voltage"
    if cw & 0x06 == 0x02:                   # bit 1 = 1, bit 2 quick stop = 0
        return "quick stop"
    low = cw & 0x0F
    if low & 0x07 == 0x06:                  # xxxx x110
        return "shutdown"
    if low == 0x07:
        return "switch on"                  # also "disable operation" from OE
    if low == 0x0F:
        return "enable operation"
    return "none"


def next_state(state: DriveState, controlword: int, previous_controlword: int = 0,
               quick_stop_option: int = 2) -> tuple[DriveState, Optional[int]]:
    """Apply one controlword; returns (new state, transition number or None if none fired).

    EPOS behaviour included: "switch on" with bit 3 set (0x0F) from READY TO SWITCH ON goes
    through transitions 3 and 4 at once (reported as 4). Quick stop option codes 5-8 stay in
    QUICK STOP ACTIVE (16 back to OE allowed); 0-4 leave it to the caller (``quick_stop_done``).
    A rising edge of bit 7 in FAULT is transition 15 (fault reset).
    """
    cmd = command_of(controlword)
    rising_reset = bool(controlword & CW_FAULT_RESET) and not (previous_controlword & CW_FAULT_RESET)
    if state is S.FAULT:
        return (S.SWITCH_ON_DISABLED, 15) if rising_reset else (state, None)
    if state in (S.FAULT_REACTION_ACTIVE, S.NOT_READY_TO_SWITCH_ON):
        return state, None
    if controlword & CW_FAULT_RESET:
        return state, None                   # bit 7 set outside FAULT: no device command
    if state is S.SWITCH_ON_DISABLED:
        return (S.READY_TO_SWITCH_ON, 2) if cmd == "shutdown" else (state, None)
    if state is S.READY_TO_SWITCH_ON:
        if cmd == "switch on":
            return S.SWITCHED_ON, 3
        if cmd == "enable operation":
            return S.OPERATION_ENABLED, 4
        if cmd in ("disable voltage", "quick stop"):
            return S.SWITCH_ON_DISABLED, 7
        return state, None
    if state is S.SWITCHED_ON:
        if cmd == "enable operation":
            return S.OPERATION_ENABLED, 4
        if cmd == "shutdown":
            return S.READY_TO_SWITCH_ON, 6
        if cmd in ("disable voltage", "quick stop"):
            return S.SWITCH_ON_DISABLED, 10
        return state, None
    if state is S.OPERATION_ENABLED:
        if cmd == "switch on":
            return S.SWITCHED_ON, 5
        if cmd == "shutdown":
            return S.READY_TO_SWITCH_ON, 8
        if cmd == "disable voltage":
            return S.SWITCH_ON_DISABLED, 9
        if cmd == "quick stop":
            if quick_stop_option == 0:
                return S.SWITCH_ON_DISABLED, 9
            return S.QUICK_STOP_ACTIVE, 11
        return state, None
    if state is S.QUICK_STOP_ACTIVE:
        if cmd == "disable voltage":
            return S.SWITCH_ON_DISABLED, 12
        if cmd == "enable operation" and 5 <= quick_stop_option <= 8:
            return S.OPERATION_ENABLED, 16
        return state, None
    return state, None


def quick_stop_done(state: DriveState, quick_stop_option: int, stopped: bool) -> tuple[DriveState, Optional[int]]:
    """Transition 12 when the quick stop has ended: option codes 1-4 go to SWITCH ON DISABLED
    once the motor stands still (``stopped``); 5-8 stay in QUICK STOP ACTIVE."""
    if state is S.QUICK_STOP_ACTIVE and 1 <= quick_stop_option <= 4 and stopped:
        return S.SWITCH_ON_DISABLED, 12
    return state, None

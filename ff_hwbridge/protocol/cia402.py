"""The CiA 402 drive state machine as tables: statusword decoding, controlword commands,
transitions keyed to the standard's numbers (0..16), and a non-blocking step planner.

Pure functions and enums, no dependencies: the master (``epos.py``) and the simulated drive
both use these tables.

Statusword (0x6041) bits used: 0 ready to switch on, 1 switched on, 2 operation enabled, 3 fault,
4 voltage enabled, 5 quick stop (active LOW: 0 = quick stop active), 6 switch on disabled,
7 warning. Controlword (0x6040) bits: 0 switch on, 1 enable voltage, 2 quick stop (active LOW),
3 enable operation, 7 fault reset (acts on the rising edge).

Transitions (CiA 402 / IEC 61800-7-201 numbering):

====  ======================  =====================  ==================================
 No.  from                    to                     cause
====  ======================  =====================  ==================================
  0   (power on / start)      Not ready to switch on automatic
  1   Not ready to switch on  Switch on disabled     automatic (drive initialised)
  2   Switch on disabled      Ready to switch on     Shutdown
  3   Ready to switch on      Switched on            Switch on
  4   Switched on             Operation enabled      Enable operation
  5   Operation enabled       Switched on            Disable operation
  6   Switched on             Ready to switch on     Shutdown
  7   Ready to switch on      Switch on disabled     Disable voltage / Quick stop
  8   Operation enabled       Ready to switch on     Shutdown
  9   Operation enabled       Switch on disabled     Disable voltage
 10   Switched on             Switch on disabled     Disable voltage / Quick stop
 11   Operation enabled       Quick stop active      Quick stop
 12   Quick stop active       Switch on disabled     Disable voltage (or quick stop done)
 13   (any)                   Fault reaction active  a fault occurs
 14   Fault reaction active   Fault                  automatic (fault reaction done)
 15   Fault                   Switch on disabled     Fault reset (rising edge of bit 7)
 16   Quick stop active       Operation enabled      Enable operation (option code 5..8)
====  ======================  =====================  ==================================
"""
from __future__ import annotations

import enum
from collections import deque
from dataclasses import dataclass
from typing import Optional


class StatuswordError(ValueError):
    """A statusword that matches no CiA 402 state (reserved bit combination)."""


class TransitionError(ValueError):
    """A target state that cannot be reached by controlword commands from the given state."""


class State(enum.Enum):
    """CiA 402 power drive system states."""

    NOT_READY_TO_SWITCH_ON = "Not ready to switch on"
    SWITCH_ON_DISABLED = "Switch on disabled"
    READY_TO_SWITCH_ON = "Ready to switch on"
    SWITCHED_ON = "Switched on"
    OPERATION_ENABLED = "Operation enabled"
    QUICK_STOP_ACTIVE = "Quick stop active"
    FAULT_REACTION_ACTIVE = "Fault reaction active"
    FAULT = "Fault"


# Statusword bits
SW_READY_TO_SWITCH_ON = 1 << 0
SW_SWITCHED_ON = 1 << 1
SW_OPERATION_ENABLED = 1 << 2
SW_FAULT = 1 << 3
SW_VOLTAGE_ENABLED = 1 << 4
SW_QUICK_STOP = 1 << 5          # 0 = quick stop active
SW_SWITCH_ON_DISABLED = 1 << 6
SW_WARNING = 1 << 7
SW_REMOTE = 1 << 9
SW_TARGET_REACHED = 1 << 10
SW_INTERNAL_LIMIT = 1 << 11

# (mask, value) of the statusword per state, as in the standard's table.
STATUSWORD_PATTERNS: dict[State, tuple[int, int]] = {
    State.NOT_READY_TO_SWITCH_ON: (0x4F, 0x00),
    State.SWITCH_ON_DISABLED: (0x4F, 0x40),
    State.READY_TO_SWITCH_ON: (0x6F, 0x21),
    State.SWITCHED_ON: (0x6F, 0x23),
    State.OPERATION_ENABLED: (0x6F, 0x27),
    State.QUICK_STOP_ACTIVE: (0x6F, 0x07),
    State.FAULT_REACTION_ACTIVE: (0x4F, 0x0F),
    State.FAULT: (0x4F, 0x08),
}


def decode_statusword(statusword: int) -> State:
    """The CiA 402 state a statusword (0x6041, u16) reports; StatuswordError if none."""
    sw = int(statusword) & 0xFFFF
    for state, (mask, value) in STATUSWORD_PATTERNS.items():
        if sw & mask == value:
            return state
    raise StatuswordError(f"statusword 0x{sw:04X} matches no CiA 402 state")


def encode_statusword(state: State, voltage_enabled: bool = True, warning: bool = False,
                      remote: bool = True, extra: int = 0) -> int:
    """A statusword reporting ``state`` (for a simulated drive); ``extra`` ORs in more bits."""
    mask, value = STATUSWORD_PATTERNS[state]
    sw = value
    # bit 5 (quick stop, active low) is outside the 0x4F mask for some states: 1 = not active
    if not mask & SW_QUICK_STOP and state is not State.QUICK_STOP_ACTIVE:
        sw |= SW_QUICK_STOP if state not in (State.NOT_READY_TO_SWITCH_ON,) else 0
    if voltage_enabled and state not in (State.NOT_READY_TO_SWITCH_ON,):
        sw |= SW_VOLTAGE_ENABLED
    if warning:
        sw |= SW_WARNING
    if remote:
        sw |= SW_REMOTE
    return (sw | int(extra)) & 0xFFFF


class Command(enum.Enum):
    """Device control commands of the controlword (0x6040)."""

    SHUTDOWN = "Shutdown"
    SWITCH_ON = "Switch on"
    DISABLE_VOLTAGE = "Disable voltage"
    QUICK_STOP = "Quick stop"
    DISABLE_OPERATION = "Disable operation"
    ENABLE_OPERATION = "Enable operation"
    FAULT_RESET = "Fault reset"


# Controlword bits
CW_SWITCH_ON = 1 << 0
CW_ENABLE_VOLTAGE = 1 << 1
CW_QUICK_STOP = 1 << 2          # 0 = quick stop
CW_ENABLE_OPERATION = 1 << 3
CW_FAULT_RESET = 1 << 7
CW_HALT = 1 << 8

# The controlword a master sends for each command.
CONTROLWORD: dict[Command, int] = {
    Command.SHUTDOWN: 0x0006,
    Command.SWITCH_ON: 0x0007,
    Command.DISABLE_VOLTAGE: 0x0000,
    Command.QUICK_STOP: 0x0002,
    Command.DISABLE_OPERATION: 0x0007,
    Command.ENABLE_OPERATION: 0x000F,
    Command.FAULT_RESET: 0x0080,
}


def decode_controlword(controlword: int, previous: Optional[int] = None) -> Optional[Command]:
    """The command a controlword carries (for a drive), by the standard's bit patterns.

    Fault reset needs the rising edge of bit 7: pass the ``previous`` controlword to detect it
    (without it, bit 7 set counts as a fault reset). Switch on and disable operation share the
    pattern 0b0111; this returns SWITCH_ON for it (the state decides which transition applies).
    None for a pattern that is no command.
    """
    cw = int(controlword) & 0xFFFF
    if cw & CW_FAULT_RESET and (previous is None or not int(previous) & CW_FAULT_RESET):
        return Command.FAULT_RESET
    if not cw & CW_ENABLE_VOLTAGE:
        return Command.DISABLE_VOLTAGE
    if not cw & CW_QUICK_STOP:
        return Command.QUICK_STOP
    low = cw & 0x0F
    if low & 0x07 == 0x06:
        return Command.SHUTDOWN
    if low == 0x07:
        return Command.SWITCH_ON
    if low == 0x0F:
        return Command.ENABLE_OPERATION
    return None


@dataclass(frozen=True)
class Transition:
    """One numbered transition: ``source`` None = any state (13) / start (0)."""

    number: int
    source: Optional[State]
    target: State
    commands: tuple[Command, ...]     # empty = automatic (internal event)


TRANSITIONS: dict[int, Transition] = {t.number: t for t in (
    Transition(0, None, State.NOT_READY_TO_SWITCH_ON, ()),
    Transition(1, State.NOT_READY_TO_SWITCH_ON, State.SWITCH_ON_DISABLED, ()),
    Transition(2, State.SWITCH_ON_DISABLED, State.READY_TO_SWITCH_ON, (Command.SHUTDOWN,)),
    Transition(3, State.READY_TO_SWITCH_ON, State.SWITCHED_ON, (Command.SWITCH_ON,)),
    Transition(4, State.SWITCHED_ON, State.OPERATION_ENABLED, (Command.ENABLE_OPERATION,)),
    Transition(5, State.OPERATION_ENABLED, State.SWITCHED_ON, (Command.DISABLE_OPERATION,)),
    Transition(6, State.SWITCHED_ON, State.READY_TO_SWITCH_ON, (Command.SHUTDOWN,)),
    Transition(7, State.READY_TO_SWITCH_ON, State.SWITCH_ON_DISABLED,
               (Command.DISABLE_VOLTAGE, Command.QUICK_STOP)),
    Transition(8, State.OPERATION_ENABLED, State.READY_TO_SWITCH_ON, (Command.SHUTDOWN,)),
    Transition(9, State.OPERATION_ENABLED, State.SWITCH_ON_DISABLED, (Command.DISABLE_VOLTAGE,)),
    Transition(10, State.SWITCHED_ON, State.SWITCH_ON_DISABLED,
               (Command.DISABLE_VOLTAGE, Command.QUICK_STOP)),
    Transition(11, State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE, (Command.QUICK_STOP,)),
    Transition(12, State.QUICK_STOP_ACTIVE, State.SWITCH_ON_DISABLED, (Command.DISABLE_VOLTAGE,)),
    Transition(13, None, State.FAULT_REACTION_ACTIVE, ()),
    Transition(14, State.FAULT_REACTION_ACTIVE, State.FAULT, ()),
    Transition(15, State.FAULT, State.SWITCH_ON_DISABLED, (Command.FAULT_RESET,)),
    Transition(16, State.QUICK_STOP_ACTIVE, State.OPERATION_ENABLED, (Command.ENABLE_OPERATION,)),
)}

# The controlword that keeps a drive in a state it has reached.
HOLD_CONTROLWORD: dict[State, int] = {
    State.NOT_READY_TO_SWITCH_ON: 0x0000,
    State.SWITCH_ON_DISABLED: 0x0000,
    State.READY_TO_SWITCH_ON: 0x0006,
    State.SWITCHED_ON: 0x0007,
    State.OPERATION_ENABLED: 0x000F,
    State.QUICK_STOP_ACTIVE: 0x0002,
    State.FAULT_REACTION_ACTIVE: 0x0000,
    State.FAULT: 0x0000,
}


def apply_command(state: State, command: Command,
                  allow_quick_stop_recovery: bool = True) -> Optional[Transition]:
    """The transition ``command`` triggers in ``state`` (a drive's view), or None (ignored).

    Switch on (0b0111) in Operation enabled is Disable operation (5). Transition 16 only when
    ``allow_quick_stop_recovery`` (quick stop option codes 5..8).
    """
    if command is Command.SWITCH_ON and state is State.OPERATION_ENABLED:
        command = Command.DISABLE_OPERATION
    for t in TRANSITIONS.values():
        if t.source is state and command in t.commands:
            if t.number == 16 and not allow_quick_stop_recovery:
                continue
            return t
    return None


def _path(current: State, target: State, allow_16: bool) -> Optional[list[Transition]]:
    """Shortest chain of command-driven transitions from ``current`` to ``target`` (BFS)."""
    edges = [t for t in TRANSITIONS.values() if t.commands and t.source is not None
             and (allow_16 or t.number != 16)]
    prev: dict[State, Optional[Transition]] = {current: None}
    queue = deque([current])
    while queue:
        s = queue.popleft()
        if s is target:
            chain: list[Transition] = []
            step = prev[s]
            while step is not None and step.source is not None:
                chain.append(step)
                step = prev[step.source]
            return chain[::-1]
        for t in sorted(edges, key=lambda e: e.number):
            if t.source is s and t.target not in prev:
                prev[t.target] = t
                queue.append(t.target)
    return None


def next_controlword(current_state: State, target_state: State,
                     previous_controlword: Optional[int] = None,
                     allow_quick_stop_recovery: bool = False) -> tuple[int, Optional[int]]:
    """One non-blocking step towards ``target_state``: ``(controlword, transition_number)``.

    Call it again on every fresh statusword. At the target it returns the hold controlword and
    None. While the drive moves on by itself (Not ready to switch on, Fault reaction active) it
    returns 0x0000 and None. From Fault the step is transition 15 (0x0080); because a fault reset
    acts on a rising edge, when ``previous_controlword`` already had bit 7 set it first returns
    0x0000 and None to clear it. Quick stop active → Operation enabled goes through Switch on
    disabled (12) unless ``allow_quick_stop_recovery`` (16). TransitionError when the target
    cannot be reached by commands (e.g. Fault, or Quick stop active from anywhere but Operation
    enabled).
    """
    if current_state is target_state:
        return HOLD_CONTROLWORD[current_state], None
    if target_state in (State.FAULT, State.FAULT_REACTION_ACTIVE, State.NOT_READY_TO_SWITCH_ON):
        raise TransitionError(f"'{target_state.value}' is entered by the drive itself, not by "
                              "a command; choose an operational target state")
    if target_state is State.QUICK_STOP_ACTIVE and current_state is not State.OPERATION_ENABLED:
        raise TransitionError("'Quick stop active' is reached only from 'Operation enabled' "
                              f"(transition 11), not from '{current_state.value}'; use "
                              "'Switch on disabled' as the safe target instead")
    if current_state in (State.NOT_READY_TO_SWITCH_ON, State.FAULT_REACTION_ACTIVE):
        return 0x0000, None
    if current_state is State.FAULT:
        if previous_controlword is not None and int(previous_controlword) & CW_FAULT_RESET:
            return 0x0000, None
        return CONTROLWORD[Command.FAULT_RESET], 15
    chain = _path(current_state, target_state, allow_quick_stop_recovery)
    if not chain:
        raise TransitionError(f"no command sequence leads from '{current_state.value}' to "
                              f"'{target_state.value}'")
    first = chain[0]
    return CONTROLWORD[first.commands[0]], first.number

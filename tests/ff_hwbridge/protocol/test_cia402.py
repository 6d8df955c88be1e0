"""CiA 402 tables: statusword decoding, controlword commands, every numbered transition, planner."""
from __future__ import annotations

import pytest

from ff_hwbridge.protocol.cia402 import (CONTROLWORD, HOLD_CONTROLWORD, STATUSWORD_PATTERNS, TRANSITIONS,
                                         Command, State, StatuswordError, TransitionError, apply_command,
                                         decode_controlword, decode_statusword, encode_statusword,
                                         next_controlword)

# Statuswords as drives report them (EPOS-style, with voltage enabled / remote bits).
SAMPLES = {
    0x0000: State.NOT_READY_TO_SWITCH_ON,
    0x0140: State.SWITCH_ON_DISABLED,
    0x0250: State.SWITCH_ON_DISABLED,
    0x0121: State.READY_TO_SWITCH_ON,
    0x0131: State.READY_TO_SWITCH_ON,
    0x0123: State.SWITCHED_ON,
    0x0133: State.SWITCHED_ON,
    0x0137: State.OPERATION_ENABLED,
    0x0437: State.OPERATION_ENABLED,
    0x0117: State.QUICK_STOP_ACTIVE,
    0x011F: State.FAULT_REACTION_ACTIVE,
    0x0108: State.FAULT,
    0x0138: State.FAULT,
}


@pytest.mark.parametrize("sw,state", sorted(SAMPLES.items()))
def test_decode_statusword_samples(sw, state):
    assert decode_statusword(sw) is state


def test_every_state_roundtrips_and_patterns_are_exclusive():
    for state in State:
        for extra in (0, 0x0080, 0x0400, 0x8000):
            assert decode_statusword(encode_statusword(state, extra=extra)) is state
    # every statusword low byte decodes to at most one state
    for sw in range(0x80):
        hits = [s for s, (m, v) in STATUSWORD_PATTERNS.items() if sw & m == v]
        assert len(hits) <= 1


def test_reserved_statusword_is_refused():
    with pytest.raises(StatuswordError):
        decode_statusword(0x0001)       # ready to switch on without bit 5 / bit 6: reserved


def test_controlword_values_and_decoding():
    assert CONTROLWORD[Command.SHUTDOWN] == 0x06
    assert CONTROLWORD[Command.SWITCH_ON] == 0x07
    assert CONTROLWORD[Command.ENABLE_OPERATION] == 0x0F
    assert CONTROLWORD[Command.DISABLE_VOLTAGE] == 0x00
    assert CONTROLWORD[Command.QUICK_STOP] == 0x02
    assert CONTROLWORD[Command.DISABLE_OPERATION] == 0x07
    assert CONTROLWORD[Command.FAULT_RESET] == 0x80
    for cmd, cw in CONTROLWORD.items():
        dec = decode_controlword(cw, previous=0)
        expect = Command.SWITCH_ON if cmd is Command.DISABLE_OPERATION else cmd
        assert dec is expect
    # fault reset only on the rising edge of bit 7
    assert decode_controlword(0x80, previous=0x80) is Command.DISABLE_VOLTAGE
    assert decode_controlword(0x86, previous=0x06) is Command.FAULT_RESET
    assert decode_controlword(0x0B) is Command.QUICK_STOP


def test_transition_table_is_the_standards():
    assert sorted(TRANSITIONS) == list(range(17))
    expect = {2: (State.SWITCH_ON_DISABLED, State.READY_TO_SWITCH_ON),
              3: (State.READY_TO_SWITCH_ON, State.SWITCHED_ON),
              4: (State.SWITCHED_ON, State.OPERATION_ENABLED),
              5: (State.OPERATION_ENABLED, State.SWITCHED_ON),
              6: (State.SWITCHED_ON, State.READY_TO_SWITCH_ON),
              7: (State.READY_TO_SWITCH_ON, State.SWITCH_ON_DISABLED),
              8: (State.OPERATION_ENABLED, State.READY_TO_SWITCH_ON),
              9: (State.OPERATION_ENABLED, State.SWITCH_ON_DISABLED),
              10: (State.SWITCHED_ON, State.SWITCH_ON_DISABLED),
              11: (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE),
              12: (State.QUICK_STOP_ACTIVE, State.SWITCH_ON_DISABLED),
              14: (State.FAULT_REACTION_ACTIVE, State.FAULT),
              15: (State.FAULT, State.SWITCH_ON_DISABLED),
              16: (State.QUICK_STOP_ACTIVE, State.OPERATION_ENABLED)}
    for n, (src, dst) in expect.items():
        assert (TRANSITIONS[n].source, TRANSITIONS[n].target) == (src, dst), n
    assert TRANSITIONS[13].source is None and TRANSITIONS[13].target is State.FAULT_REACTION_ACTIVE
    assert not TRANSITIONS[0].commands and not TRANSITIONS[1].commands and not TRANSITIONS[14].commands


@pytest.mark.parametrize("number", [n for n, t in TRANSITIONS.items() if t.commands])
def test_every_command_transition_by_controlword(number):
    """A drive applying the decoded controlword of each command transition lands on its target."""
    t = TRANSITIONS[number]
    for cmd in t.commands:
        cw = CONTROLWORD[cmd]
        decoded = decode_controlword(cw, previous=0)
        got = apply_command(t.source, decoded)
        assert got is not None and got.target is t.target
        if number in (7, 10) or (number == 12 and cmd is Command.DISABLE_VOLTAGE):
            assert got.number == number
    assert apply_command(State.QUICK_STOP_ACTIVE, Command.ENABLE_OPERATION,
                         allow_quick_stop_recovery=False) is None


@pytest.mark.parametrize("current", list(State))
@pytest.mark.parametrize("target", [State.SWITCH_ON_DISABLED, State.READY_TO_SWITCH_ON,
                                    State.SWITCHED_ON, State.OPERATION_ENABLED])
def test_planner_reaches_every_operational_target(current, target):
    """Simulate a drive following next_controlword; automatic states move on by themselves."""
    state, prev = current, 0
    for _ in range(8):
        cw, number = next_controlword(state, target, prev)
        if state is target:
            assert number is None and cw == HOLD_CONTROLWORD[target]
            return
        if state is State.NOT_READY_TO_SWITCH_ON:
            state = State.SWITCH_ON_DISABLED               # transition 1
        elif state is State.FAULT_REACTION_ACTIVE:
            state = State.FAULT                            # transition 14
        else:
            t = apply_command(state, decode_controlword(cw, prev), allow_quick_stop_recovery=False)
            if number is not None:
                assert t is not None and t.number == number
                state = t.target
        prev = cw
    pytest.fail(f"{current} -> {target} not reached")


def test_planner_first_steps():
    assert next_controlword(State.SWITCH_ON_DISABLED, State.OPERATION_ENABLED) == (0x06, 2)
    assert next_controlword(State.READY_TO_SWITCH_ON, State.OPERATION_ENABLED) == (0x07, 3)
    assert next_controlword(State.SWITCHED_ON, State.OPERATION_ENABLED) == (0x0F, 4)
    assert next_controlword(State.OPERATION_ENABLED, State.SWITCHED_ON) == (0x07, 5)
    assert next_controlword(State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE) == (0x02, 11)
    assert next_controlword(State.OPERATION_ENABLED, State.SWITCH_ON_DISABLED) == (0x00, 9)
    assert next_controlword(State.QUICK_STOP_ACTIVE, State.OPERATION_ENABLED) == (0x00, 12)
    assert next_controlword(State.QUICK_STOP_ACTIVE, State.OPERATION_ENABLED,
                            allow_quick_stop_recovery=True) == (0x0F, 16)
    assert next_controlword(State.FAULT, State.OPERATION_ENABLED, 0x00) == (0x80, 15)
    assert next_controlword(State.FAULT, State.OPERATION_ENABLED, 0x80) == (0x00, None)


def test_planner_refuses_unreachable_targets():
    for bad in (State.FAULT, State.FAULT_REACTION_ACTIVE, State.NOT_READY_TO_SWITCH_ON):
        with pytest.raises(TransitionError):
            next_controlword(State.SWITCHED_ON, bad)
    with pytest.raises(TransitionError, match="Operation enabled"):
        next_controlword(State.SWITCH_ON_DISABLED, State.QUICK_STOP_ACTIVE)

"""The CiA 402 state machine from the master's side: a target state per drive, reached one
non-blocking controlword step per received statusword (``cia402.next_controlword``), and what a
player may send (``gate``). canopen's BaseNode402 is not used (it blocks waiting for statuswords)."""
from __future__ import annotations

import logging
import time
from typing import Optional


from ff_hwbridge.drive.node import (REFRESH_PERIOD, RESEND_PERIOD,
                                    EposError, MasterBase, _Drive)
from ff_hwbridge.protocol import cia402
from ff_hwbridge.protocol.cia402 import State

log = logging.getLogger("ff_hwbridge.drive.epos")

__all__ = ["StateMachine"]


class StateMachine(MasterBase):
    """EposMaster's part: the CiA 402 state machine."""

    def _step(self, d: _Drive, now: float) -> None:
        """One non-blocking state-machine step after a fresh statusword."""
        state = d.feedback.state
        if state is None or not d.operational:
            return
        if state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
            if now >= d.reset_until and not self.guard.latched:
                d.history_wanted = True
                self.trip(f"drive fault: node {d.node_id} ({d.cfg.name}) is in '{state.value}' "
                          f"(statusword 0x{d.feedback.statusword:04X})"
                          + (f"; last {d.emcy[-1]}" if d.emcy else ""))
            if now >= d.reset_until:
                return           # stay in Fault until an explicit fault reset
        with self._send_lock:     # decide and send atomically w.r.t. command_currents
            target = d.target
            if target is State.QUICK_STOP_ACTIVE and state not in (State.OPERATION_ENABLED,
                                                                   State.QUICK_STOP_ACTIVE):
                target = State.SWITCH_ON_DISABLED
            try:
                cw, _ = cia402.next_controlword(state, target, d.rpdo.controlword)
            except cia402.TransitionError:
                cw = cia402.HOLD_CONTROLWORD.get(state, 0)
            setpoint = d.rpdo.setpoint if (state is State.OPERATION_ENABLED
                                      and target is State.OPERATION_ENABLED
                                      and not self.guard.latched) else 0
            # RPDOs are not acknowledged: sync, every SYNC cycle repeats them (``_on_cycle``);
            # on_receipt, while the drive is not where we want it, repeat the controlword (a
            # lost quick stop must not leave the drive driving current), and refresh the RPDO
            # now and then anyway (a lost setpoint heals)
            since = now - d.rpdo.last_tx
            if self._player_owns(d) and cw == d.rpdo.controlword:
                return                    # the player's RPDOs (one per cycle) carry it
            repeat = not self.config.synchronous and ((state is not target and since >= RESEND_PERIOD)
                                                      or since >= REFRESH_PERIOD)
            if cw != d.rpdo.controlword or setpoint != d.rpdo.setpoint or repeat:
                self._send_rpdo(d, cw, setpoint)

    def gate(self) -> list[tuple[int, bool]]:
        """Per joint: (controlword, True when a current may be sent: operational, in and meant
        for Operation enabled, no safe state latched)."""
        latched = self.guard.latched
        return [(d.rpdo.controlword, bool(not latched and d.operational
                                     and d.feedback.state is State.OPERATION_ENABLED
                                     and d.target is State.OPERATION_ENABLED))
                for d in self._drives]

    def _gate_changed(self) -> None:
        fn = self.gate_listener
        if fn is not None:
            try:
                fn()
            except Exception:  # noqa: BLE001 - the caller is the state machine / a reaction
                log.exception("gate listener failed")

    def _player_owns(self, d: _Drive) -> bool:
        """An external player feeds this enabled drive's RPDO (no refresh from here)."""
        return (self.external_player and not self.guard.latched
                and d.feedback.state is State.OPERATION_ENABLED
                and d.target is State.OPERATION_ENABLED)

    def _set_target(self, target: State) -> None:
        now = self.clock()
        for d in self._drives:
            d.target = target
        if self.external_player:
            self._gate_changed()
        for d in self._drives:
            if d.feedback.state is not None:
                self._step(d, now)

    def enable(self) -> None:
        """Request Operation enabled (zero current); refused (EposError) while latched."""
        if self.guard.latched:
            raise EposError(f"safe state latched ({self.guard.reason}); call fault_reset() first")
        for d in self._drives:
            d.rpdo.setpoint = 0
        self._set_target(State.OPERATION_ENABLED)

    def disable(self) -> None:
        """Zero current, then request Switched on (disable operation, transition 5)."""
        self.command_zero()
        self._set_target(State.SWITCHED_ON)

    def disable_voltage(self) -> None:
        """Zero current, request Switch on disabled."""
        self.command_zero()
        self._set_target(State.SWITCH_ON_DISABLED)

    def quick_stop(self, reason: str = "quick stop requested") -> None:
        """Latch the safe state: zero current and quick stop."""
        self.trip(reason)

    def estop(self, reason: str = "requested") -> str:
        """Emergency stop: latch the safe state (zero current, quick stop) with ``reason``;
        returns the reason in force (an earlier latch keeps its own)."""
        self.trip(f"e-stop: {reason}")
        return self.guard.reason or f"e-stop: {reason}"

    def wait_for_state(self, state: State, timeout: Optional[float] = None) -> bool:
        """Block until every drive reports ``state`` (polling); False on timeout or a latch."""
        deadline = self.clock() + (self.config.state_timeout if timeout is None else timeout)
        while self.clock() < deadline:
            if all(d.feedback.state is state for d in self._drives):
                return True
            if self.guard.latched and state is State.OPERATION_ENABLED:
                return False
            time.sleep(0.002)
        return all(d.feedback.state is state for d in self._drives)

"""The setpoint RPDO writer: RPDO1 (controlword + raw setpoint, clamped to the raw limit) per
drive, the cycle contract of the cyclic synchronous modes (every SYNC seen opens a cycle in which
each operational drive gets its RPDO1 once, the value in force repeated when nothing new went out
in it: ``_on_cycle``, on the bus receiver's thread, user space, so a frozen process falls silent
and the drive's interpolation-period supervision, EMCY 0x8250, stops it), the echoes of its own
frames (their bus instants), and guard + units of the commands."""
from __future__ import annotations

import logging
import struct
import time
from typing import Any, Callable, Optional, Sequence

import numpy as np

from ff_hwbridge.drive.node import (MasterBase, PreparedCommand, _Drive)
from ff_hwbridge.drive.safety import SafeCommand
from ff_hwbridge.protocol.cia402 import State

log = logging.getLogger("ff_hwbridge.drive.epos")

__all__ = ["RpdoWriter"]


class RpdoWriter(MasterBase):
    """EposMaster's part: the setpoint RPDO writer."""

    def _sync_fresh(self) -> bool:
        """A SYNC came within the last three periods (the reaction's RPDO will be latched)."""
        age = self.sync_watch.age_s() if self.sync_watch is not None else None
        return age is not None and age < 3.0 * float(self.config.sync_period)

    def _send_sdo_controlword(self, d: _Drive, controlword: int) -> None:
        """Write 0x6040 with one expedited SDO download frame (CiA 301: command 0x2B, 2 bytes),
        without waiting for the answer: the safe state must not block on a drive or bus that
        does not answer (canopen's SDO client drops the stray answer before its next request)."""
        data = struct.pack("<BHBH2x", 0x2B, 0x6040, 0, int(controlword) & 0xFFFF)
        with self._send_lock:
            try:
                self._connected_network().send_message(0x600 + d.node_id, data)
            except Exception:  # noqa: BLE001 - a full bus must not kill the caller's thread
                self.tx_errors += 1
                log.exception("SDO controlword to node %d failed", d.node_id)

    def _send_rpdo(self, d: _Drive, controlword: int, setpoint: int) -> None:
        """Send RPDO1 (controlword + raw setpoint, clamped to the raw limit)."""
        sp = max(-d.raw_limit, min(d.raw_limit, int(setpoint)))
        if self.guard.latched or self.external_player:
            sp = 0
        data = struct.pack(d.rx_fmt, int(controlword) & 0xFFFF, sp)
        with self._send_lock:
            changed = d.controlword != int(controlword) & 0xFFFF
            d.controlword = int(controlword) & 0xFFFF
            d.setpoint = sp
            d.last_tx = self.clock()
            d.cycle_sent = self.sync_watch.count
            if changed and self.external_player:
                self._gate_changed()      # the player learns the new controlword first
            try:
                self._connected_network().send_message(0x200 + d.node_id, data)
                d.tx_seq += 1
            except Exception:  # noqa: BLE001 - a full bus must not kill the caller's thread
                self.tx_errors += 1
                d.tx_failing += 1
                if d.tx_failing == 1:    # a lost bus fails every cycle: one traceback, then a count
                    log.exception("RPDO to node %d failed (the next failures are counted, not "
                                  "logged, until one goes through)", d.node_id)
                return
            if d.tx_failing:
                log.warning("RPDO to node %d goes through again after %d failed", d.node_id,
                            d.tx_failing)
                d.tx_failing = 0

    def _on_cycle(self, ev: Any) -> None:
        """A SYNC seen (bus receiver's thread; ``ev`` a SyncEvent): the cycle it opens gets each
        operational drive's RPDO1 once: the value in force (controlword, setpoint) again when
        nothing went out since this SYNC. A player in another process does it for the enabled
        drives it feeds. A later new setpoint in the same cycle replaces it (the drive latches
        the last one before the SYNC)."""
        if self.network is None:
            return
        for d in self._drives:
            if not d.operational or d.cycle_sent >= ev.count:
                continue
            with self._send_lock:
                if d.operational and d.cycle_sent < ev.count and not self._player_owns(d):
                    d.cycle_repeats += 1
                    self._send_rpdo(d, d.controlword, d.setpoint)

    def _make_echo_cb(self, d: _Drive) -> Callable[[int, bytearray, float], None]:
        def on_echo(can_id: int, data: bytearray, timestamp: float) -> None:
            d.echo_seq += 1
            d.echo_log.append((d.echo_seq, int(round(timestamp * 1e9)) if timestamp else time.time_ns()))
        return on_echo

    def echo_time(self, marks: Sequence[int]) -> Optional[int]:
        """Bus instant (wall ns) by which the RPDOs numbered ``marks`` (``send_prepared``'s
        return, per joint) were all on the bus, from their echoes; None while one is missing."""
        latest = 0
        for d, m in zip(self._drives, marks):
            if m <= 0:
                continue
            log_ = list(d.echo_log)        # a copy: the receiver thread appends meanwhile
            i = m - log_[0][0] if log_ else -1     # echo numbers are consecutive
            if not 0 <= i < len(log_):
                return None
            latest = max(latest, log_[i][1])
        return latest

    def rpdo_marks(self) -> tuple[int, ...]:
        """Per joint, how many setpoint RPDOs have been handed to the bus (compare with the
        echo counts of a :class:`~ff_hwbridge.drive.sync_watch.SyncEvent`)."""
        return tuple(d.tx_seq for d in self._drives)

    def prepare_currents(self, amps: Sequence[float]) -> PreparedCommand:
        """Guard + unit conversion of motor currents (A, one per joint), nothing sent yet: lets a
        player do the work before a stamp and only ``send_prepared`` at it."""
        cmd = self.guard.filter(amps)
        raws = tuple(d.units.amps_to_setpoint(float(a), limit=d.cfg.current_limit)
                     for d, a in zip(self._drives, cmd.currents))
        return PreparedCommand(cmd, raws)

    def send_prepared(self, prepared: PreparedCommand) -> tuple[int, ...]:
        """Send prepared setpoints (one RPDO per joint). Zero while latched or when a drive is
        not (to be) in Operation enabled; the raw value is clamped to the limit once more.
        Returns per joint the RPDO count including these (``rpdo_marks`` right after each)."""
        marks = []
        for d, raw in zip(self._drives, prepared.raw):
            with self._send_lock:
                if (self.guard.latched or d.feedback.state is not State.OPERATION_ENABLED
                        or d.target is not State.OPERATION_ENABLED):
                    raw = 0
                if d.operational:
                    self._send_rpdo(d, d.controlword, raw)
                marks.append(d.tx_seq)
        return tuple(marks)

    def command_currents(self, amps: Sequence[float]) -> SafeCommand:
        """Send motor currents (A, one per joint) through the guard now; returns what was sent."""
        prepared = self.prepare_currents(amps)
        self.send_prepared(prepared)
        return prepared.command

    def command_zero(self) -> None:
        """Zero current on every joint (no latch)."""
        for d in self._drives:
            if d.operational:
                self._send_rpdo(d, d.controlword, 0)
            d.setpoint = 0

    def applied_currents(self) -> np.ndarray:
        """A, the currents last sent (from the raw setpoints)."""
        return np.array([d.units.setpoint_to_amps(d.setpoint) for d in self._drives])

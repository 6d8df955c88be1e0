"""The setpoint RPDO, once for both player placements.

:class:`SetpointRpdos` is the setpoint RPDO1 of a drive group (per drive one
:class:`RpdoChannel`): the frame (controlword + raw setpoint, clamped to the raw current limit,
0 while the placement says the current must be 0: :func:`rpdo_frame`), the record of the value
in force, the cycle contract of the cyclic synchronous modes (every SYNC seen opens a cycle in
which each drive this writer owns gets its RPDO1 once, the value in force repeated when nothing
new went out in it: :meth:`SetpointRpdos.on_cycle`, on the bus receiver's thread, user space, so
a frozen process falls silent and the drive's interpolation-period supervision, EMCY 0x8250,
stops it) and the echoes of its own frames (their bus instants, :meth:`SetpointRpdos.echo_time`).

The two placements differ only in the parameters they give it:

- the master in the bridge's process (:class:`RpdoWriter`, part of ``EposMaster``) owns an
  operational drive's RPDO unless a player process feeds it; it is the only sender of the
  COB-ID on its connection, so every frame of it the bus echoes is its own
  (``EchoMatch.EVERY_FRAME``); a failing send is counted, the caller goes on;
- the player process's link (``player_process.ChildLink``) owns the RPDO of a drive while the
  master's gate lets it send a current, with the gate's controlword; the master's own frames of
  the COB-ID (its controlword steps, its safe-state zero) reach it too, so a frame is its own
  when it equals the oldest one not yet echoed (``EchoMatch.SENT_FRAMES``); it forgets the value
  in force when the master takes a drive back; a failing send raises (the player reports it).

:class:`RpdoWriter` adds the master's guard + units of the commands.
"""
from __future__ import annotations

import enum
import logging
import struct
import threading
import time
from typing import Any, Callable, Optional, Sequence

import numpy as np

from ff_hwbridge.drive.node import MasterBase, PreparedCommand, RpdoChannel, _Drive
from ff_hwbridge.drive.safety import SafeCommand
from ff_hwbridge.protocol.cia402 import State

log = logging.getLogger("ff_hwbridge.drive.epos")

__all__ = ["EchoMatch", "RpdoChannel", "RpdoWriter", "SetpointRpdos", "rpdo_frame"]

ECHO_LOG = 4096           # RPDO numbers whose echo instants are kept, per drive


class EchoMatch(enum.Enum):
    """How a writer tells its own RPDOs among the frames of their COB-ID the bus echoes."""

    EVERY_FRAME = "every frame"     # the only sender of the COB-ID on this connection
    SENT_FRAMES = "sent frames"     # another sender shares it: ours equal the oldest unechoed


def rpdo_frame(fmt: str, raw_limit: int, controlword: int, setpoint: int) -> tuple[bytes, int]:
    """RPDO1 data (controlword, raw setpoint clamped to ±``raw_limit``) and the setpoint in it."""
    sp = max(-int(raw_limit), min(int(raw_limit), int(setpoint)))
    return struct.pack(fmt, int(controlword) & 0xFFFF, sp), sp


class SetpointRpdos:
    """The setpoint RPDO1s of a drive group (module docstring).

    transmit(cob_id, data): puts one frame on the bus (raises on failure).
    sync_count():           the SYNC count of the cycle now open (``SyncWatch.count``).
    owner(i):               the controlword to repeat when this writer owns drive ``i``'s
                            RPDO in a cycle, None when it does not.
    zero_current():         True: every frame carries 0 current (a safe state, another owner).
    echo:                   how the bus's echoes of our frames are recognised.
    forget_when_not_owned:  the value in force becomes 0 in a cycle this writer does not own.
    on_send_error(i, exc):  a failed send is counted and dropped (None: it raises).
    lock:                   held around a send and its record (an RLock: a caller may hold it)."""

    def __init__(self, channels: Sequence[RpdoChannel], transmit: Callable[[int, bytes], None],
                 sync_count: Callable[[], int], *, owner: Callable[[int], Optional[int]],
                 zero_current: Callable[[], bool], echo: EchoMatch, forget_when_not_owned: bool = False,
                 on_send_error: Optional[Callable[[int, Exception], None]] = None,
                 lock: Optional[Any] = None, clock: Callable[[], float] = time.monotonic) -> None:
        self.channels = list(channels)
        self._transmit = transmit
        self._sync_count = sync_count
        self._owner = owner
        self._zero_current = zero_current
        self.echo = echo
        self.forget_when_not_owned = forget_when_not_owned
        self._on_send_error = on_send_error
        self.lock = lock if lock is not None else threading.RLock()
        self._clock = clock
        self._by_cob = {ch.cob_id: i for i, ch in enumerate(self.channels)}

    def index(self, cob_id: int) -> Optional[int]:
        """The drive whose RPDO1 has ``cob_id`` (None: not one of ours)."""
        return self._by_cob.get(cob_id)

    def send(self, i: int, controlword: int, setpoint: int) -> int:
        """RPDO1 of drive ``i`` now (clamped; 0 current while ``zero_current()``), recorded as
        the value in force; returns its RPDO number (``tx_seq``; unchanged when it failed)."""
        ch = self.channels[i]
        with self.lock:               # a cycle's repeat never goes between a send and its record
            data, sp = rpdo_frame(ch.fmt, ch.raw_limit, controlword, 0 if self._zero_current() else setpoint)
            ch.controlword = int(controlword) & 0xFFFF
            ch.setpoint = sp
            ch.last_tx = self._clock()
            ch.cycle_sent = self._sync_count()
            matched = self.echo is EchoMatch.SENT_FRAMES
            if matched:               # recorded first: its echo may come before send returns
                ch.unechoed.append((ch.tx_seq + 1, data))
            try:
                self._transmit(ch.cob_id, data)
            except Exception as exc:
                if matched:
                    ch.unechoed.pop()
                ch.tx_failing += 1
                if self._on_send_error is None:
                    raise
                if ch.tx_failing == 1:    # a lost bus fails every cycle: one traceback, then a count
                    log.exception("RPDO to node %d failed (the next failures are counted, not "
                                  "logged, until one goes through)", ch.cob_id - 0x200)
                self._on_send_error(i, exc)
                return ch.tx_seq
            ch.tx_seq += 1
            if ch.tx_failing:
                log.warning("RPDO to node %d goes through again after %d failed", ch.cob_id - 0x200,
                            ch.tx_failing)
                ch.tx_failing = 0
            return ch.tx_seq

    def on_cycle(self, ev: Any) -> None:
        """A SYNC seen (bus receiver's thread; ``ev`` a SyncEvent): each drive this writer owns
        gets its RPDO1 once in the cycle it opens, the value in force again when nothing went
        out since this SYNC. A later new setpoint in the same cycle replaces it (the drive
        latches the last one before the SYNC)."""
        for i, ch in enumerate(self.channels):
            with self.lock:
                cw = self._owner(i)
                if cw is None:
                    if self.forget_when_not_owned:
                        ch.setpoint = 0       # 0 when the other owner hands the drive back
                    continue
                if ch.cycle_sent >= ev.count:
                    continue
                ch.repeats += 1
                self.send(i, cw, ch.setpoint)

    def forget(self) -> None:
        """The value in force 0 on every drive (a safe state or fault reset)."""
        with self.lock:
            for ch in self.channels:
                ch.setpoint = 0

    def on_echo(self, i: int, data: bytes, bus_ns: int) -> bool:
        """A frame of drive ``i``'s RPDO1 COB-ID echoed by the bus at ``bus_ns`` (wall ns);
        True when it was one of ours (then its instant is logged under its RPDO number)."""
        ch = self.channels[i]
        if self.echo is EchoMatch.SENT_FRAMES:
            sent = ch.unechoed          # the bus echoes our frames in send order
            if not sent or sent[0][1] != bytes(data):
                return False
            seq = sent.popleft()[0]
        else:
            seq = ch.echo_seq + 1
        ch.echo_seq += 1
        ch.echo_log[seq] = bus_ns
        ch.echo_log.pop(seq - ECHO_LOG, None)
        return True

    def echo_time(self, marks: Sequence[int]) -> Optional[int]:
        """Bus instant (wall ns) by which the RPDOs numbered ``marks`` (per drive; 0: none)
        were all on the bus, from their echoes; None while one is missing."""
        latest = 0
        for ch, m in zip(self.channels, marks):
            if m <= 0:
                continue
            t = ch.echo_log.get(m)
            if t is None:
                return None
            latest = max(latest, t)
        return latest

    def marks(self) -> tuple[int, ...]:
        """Per drive, how many RPDOs have been handed to the bus."""
        return tuple(ch.tx_seq for ch in self.channels)

    def echoes(self) -> tuple[int, ...]:
        """Per drive, how many of ours the bus has echoed."""
        return tuple(ch.echo_seq for ch in self.channels)

    @property
    def repeats(self) -> int:
        return sum(ch.repeats for ch in self.channels)


class RpdoWriter(MasterBase):
    """EposMaster's part: its :class:`SetpointRpdos` (owner of an operational drive's RPDO
    unless a player process feeds it; every echoed frame of the COB-ID its own), the SDO
    controlword and guard + units of the commands."""

    rpdos: SetpointRpdos

    def _make_rpdos(self) -> SetpointRpdos:
        """The master's writer over its drives' channels (``EposMaster.__init__``)."""
        for i, d in enumerate(self._drives):
            d.index = i
            d.rpdo = RpdoChannel(cob_id=0x200 + d.node_id)

        def owner(i: int) -> Optional[int]:
            d = self._drives[i]
            if self.network is None or not d.operational or self._player_owns(d):
                return None
            return d.rpdo.controlword

        def failed(i: int, exc: Exception) -> None:
            self.tx_errors += 1

        return SetpointRpdos([d.rpdo for d in self._drives],
                             lambda cob, data: self._connected_network().send_message(cob, data),
                             lambda: self.sync_watch.count, owner=owner,
                             zero_current=lambda: self.guard.latched or self.external_player,
                             echo=EchoMatch.EVERY_FRAME, on_send_error=failed, lock=self._send_lock,
                             clock=self.clock)

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
        """Send RPDO1 (controlword + raw setpoint, clamped to the raw limit; 0 current while
        latched or while a player process owns the currents)."""
        with self._send_lock:
            cw = int(controlword) & 0xFFFF
            if cw != d.rpdo.controlword and self.external_player:
                d.rpdo.controlword = cw
                self._gate_changed()      # the player learns the new controlword first
            self.rpdos.send(d.index, cw, setpoint)

    def _on_cycle(self, ev: Any) -> None:
        """A SYNC seen: each drive this master owns gets its RPDO1 once in the cycle it opens."""
        self.rpdos.on_cycle(ev)

    def _make_echo_cb(self, d: _Drive) -> Callable[[int, bytearray, float], None]:
        i = d.index

        def on_echo(can_id: int, data: bytearray, timestamp: float) -> None:
            self.rpdos.on_echo(i, bytes(data), int(round(timestamp * 1e9)) if timestamp else time.time_ns())
        return on_echo

    def echo_time(self, marks: Sequence[int]) -> Optional[int]:
        """Bus instant (wall ns) by which the RPDOs numbered ``marks`` (``send_prepared``'s
        return, per joint) were all on the bus, from their echoes; None while one is missing."""
        return self.rpdos.echo_time(marks)

    def rpdo_marks(self) -> tuple[int, ...]:
        """Per joint, how many setpoint RPDOs have been handed to the bus (compare with the
        echo counts of a :class:`~ff_hwbridge.drive.sync_watch.SyncEvent`)."""
        return self.rpdos.marks()

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
                    self._send_rpdo(d, d.rpdo.controlword, raw)
                marks.append(d.rpdo.tx_seq)
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
                self._send_rpdo(d, d.rpdo.controlword, 0)
            d.rpdo.setpoint = 0

    def applied_currents(self) -> np.ndarray:
        """A, the currents last sent (from the raw setpoints)."""
        return np.array([d.units.setpoint_to_amps(d.rpdo.setpoint) for d in self._drives])

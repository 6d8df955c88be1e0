"""The feedback receiver: TPDO1 (statusword + position) and TPDO2 (velocity + current) decoded into
immutable :class:`~ff_hwbridge.drive.feedback.JointFeedback` snapshots, each TPDO1 placed at the
SYNC it answers where the pairing is certain (:class:`~ff_hwbridge.drive.feedback.SamplePairing`),
statusword bit 11 recorded per motion, and one state-machine step per statusword."""
from __future__ import annotations

import logging
import struct
import time
from dataclasses import replace
from typing import Any, Callable, Optional


from ff_hwbridge.drive.feedback import JointFeedback
from ff_hwbridge.drive.node import (MasterBase, _Drive)
from ff_hwbridge.protocol import cia402
from ff_hwbridge.protocol.cia402 import SW_INTERNAL_LIMIT, State

log = logging.getLogger("ff_hwbridge.drive.epos")

__all__ = ["FeedbackReceiver"]


class FeedbackReceiver(MasterBase):
    """EposMaster's part: the feedback receiver."""

    def feedback(self) -> list[JointFeedback]:
        """The latest feedback per joint (immutable snapshots, each from one TPDO1 / TPDO2)."""
        return [d.feedback for d in self._drives]

    def _publish(self, d: _Drive, **changes: Any) -> JointFeedback:
        """Swap in a new feedback snapshot of ``d`` with ``changes``."""
        with self._fb_lock:
            d.feedback = fb = replace(d.feedback, **changes)
        return fb

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """A SYNC on the bus (receiver thread): its bus instant and the echoes before it."""
        echoes = tuple(d.rpdo.echo_seq for d in self._drives) if self.echo else None
        ev = self.sync_watch.observe(timestamp, echoes)
        for d in self._drives:
            at = d.pairing.on_sync(ev.bus_ns) if d.pairing is not None else None
            if at is not None:           # a TPDO received before the SYNC it answers
                self._publish(d, sample_ns=at)

    def _make_tpdo1_cb(self, d: _Drive) -> Callable[[int, bytearray, float], None]:
        fmt = d.tx1_fmt
        size = struct.calcsize(fmt)

        def on_tpdo1(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) < size:
                return
            sw, pos = struct.unpack_from(fmt, data)
            try:
                state: Optional[State] = cia402.decode_statusword(sw)
            except cia402.StatuswordError:
                state = None
            now = self.clock()
            tpdo_ns = int(round(timestamp * 1e9)) if timestamp else time.time_ns()
            sample_ns = self._sample_instant(d, tpdo_ns, proxy)
            before = d.feedback.state
            fb = self._publish(d, statusword=sw, position_raw=pos, position=d.units.increments_to_rad(pos),
                               state=state, stamp=now, sample_ns=sample_ns)
            if state is not before and self.external_player:
                self._gate_changed()
            d.tpdo_seen = True
            # counted from a motion's start until the next one starts, not only while its
            # setpoints arrive: they arrive a lead time ahead of the instants the drive applies them
            if sw & SW_INTERNAL_LIMIT and d.limited_armed:
                if not d.limited_count:
                    d.limited_first_ns = fb.sample_ns
                d.limited_count += 1
            if proxy:
                # no echo of our own SYNC: the first drive's synchronous TPDO1 marks the cycle
                self.sync_watch.observe(timestamp, None)
            self._step(d, now)
        proxy = (d is self._drives[0] and self.config.sync_producer == "master" and not self.echo)
        return on_tpdo1

    def _sample_instant(self, d: _Drive, tpdo_ns: int, proxy: bool) -> int:
        """Wall ns at which a synchronous TPDO's values were sampled: the SYNC it answers when
        the pairing is certain (``SamplePairing``), else its own bus instant."""
        if proxy or d.pairing is None or (self.config.sync_producer == "master" and not self.echo):
            return tpdo_ns              # our own SYNC is not seen on this bus: no better instant
        return d.pairing.on_tpdo(tpdo_ns)

    def _make_tpdo2_cb(self, d: _Drive) -> Callable[[int, bytearray, float], None]:
        fmt = d.tx2_fmt
        size = struct.calcsize(fmt)

        def on_tpdo2(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) < size:
                return
            rpm, cur = struct.unpack_from(fmt, data)
            self._publish(d, velocity_raw=rpm, current_raw=cur, velocity=d.units.rpm_to_rad_s(rpm),
                          current=d.units.ma_to_amps(cur), stamp_motion=self.clock())
        return on_tpdo2

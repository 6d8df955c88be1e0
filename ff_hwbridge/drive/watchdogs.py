"""The master's watchdogs and its safe state: the monitor thread (heartbeat loss, TPDO silence,
SYNC loss, a failed bus, the position / velocity envelope, the setpoint watchdog), the heartbeat
and EMCY listeners, and ``trip`` / ``_react``: latch the reason (first wins), raise the reset
epoch, quick stop (or disable voltage) with zero current, as an SDO write too when SYNC is gone,
then tell the fault listeners."""
from __future__ import annotations

import logging
import math
import threading
import time
from typing import Any, Callable, Optional


from ff_hwbridge.drive.node import (NMT_STATES, REFRESH_PERIOD, SYNC_COB_ID, MasterBase, _Drive)
from ff_hwbridge.protocol import cia402
from ff_hwbridge.protocol.cia402 import State
from ff_hwbridge.protocol.epos_errors import describe

log = logging.getLogger("ff_hwbridge.drive.epos")

__all__ = ["Watchdogs"]


class Watchdogs(MasterBase):
    """EposMaster's part: watchdogs and the safe state."""

    def _start_monitor(self) -> None:
        if self._monitor is None or not self._monitor.is_alive():
            self._monitor_stop.clear()
            self._monitor = threading.Thread(target=self._monitor_loop, name="ff-epos-monitor",
                                             daemon=True)
            self._monitor.start()

    def _stop_monitor(self) -> None:
        self._monitor_stop.set()
        if self._monitor is not None:
            self._monitor.join(2.0)
            self._monitor = None

    def _monitor_loop(self) -> None:
        while not self._monitor_stop.wait(self.config.monitor_period):
            try:
                now = self.clock()
                self.check(now)
                for d in self._drives:
                    # on_receipt: keep the RPDO stream fed even when no TPDO arrives to step
                    # the state machine (sync: every SYNC cycle does, ``_on_cycle``)
                    if (not self.config.synchronous and d.operational and d.feedback.state is not None
                            and not self._player_owns(d) and now - d.rpdo.last_tx >= REFRESH_PERIOD):
                        with self._send_lock:
                            self._send_rpdo(d, d.rpdo.controlword, d.rpdo.setpoint)
                    if d.history_wanted and d.operational:
                        d.history_wanted = False
                        self.read_error_history(d.cfg.name)
            except Exception:  # noqa: BLE001 - the monitor must keep running
                log.exception("monitor check failed")

    def check(self, now: float) -> Optional[str]:
        """Heartbeat / feedback timeouts and the setpoint watchdog at ``now``; returns a new
        fault reason if this call latched the safe state."""
        timeout = self.config.heartbeat_timeout
        reason = self._check_bus()
        if reason:
            return self.trip(reason)
        reason = self._check_sync(now)     # first: without SYNC the TPDOs stop too
        if reason:
            return self.trip(reason)
        for d in self._drives:
            if not d.operational:
                continue
            # until the first OPERATIONAL heartbeat / first TPDO after NMT start, allow
            # state_timeout (a drive may take a while to start its PDOs)
            grace = max(timeout, self.config.state_timeout)
            hb_limit = timeout if d.seen_operational else grace
            if d.last_heartbeat is not None and now - d.last_heartbeat > hb_limit:
                return self.trip(f"heartbeat lost: node {d.node_id} ({d.cfg.name}) silent for "
                                 f"{(now - d.last_heartbeat) * 1000.0:.0f} ms (timeout "
                                 f"{hb_limit * 1000.0:.0f} ms)")
            fb_limit = self.config.feedback_timeout if d.tpdo_seen else max(self.config.feedback_timeout, grace)
            if self.sync_expected and now - d.feedback.stamp > fb_limit:
                return self.trip(f"feedback lost: no TPDO from node {d.node_id} ({d.cfg.name}) for "
                                 f"{(now - d.feedback.stamp) * 1000.0:.0f} ms (timeout "
                                 f"{fb_limit * 1000.0:.0f} ms)")
            reason = self._envelope(d)
            if reason:
                return self.trip(reason)
        reason = self.guard.check(now, pending=self.pending_fn())
        if reason:
            self._react(reason)
            return reason
        return None

    def _check_bus(self) -> Optional[str]:
        """The bus itself failed: python-can's notifier stops its reader thread and keeps the
        exception (bus off, adapter unplugged, the simulation's hub gone). Said at once, instead
        of the heartbeat or SYNC loss that follows a timeout later. Once latched it is reported
        once; a configure (a new connection) is needed to run again."""
        notifier = getattr(self.network, "notifier", None)
        exc = getattr(notifier, "exception", None)
        if exc is None or self._bus_lost_told:
            return None
        self._bus_lost_told = True
        return f"CAN bus lost: {type(exc).__name__}: {exc} (configure again once the bus is back)"

    def _check_sync(self, now: float) -> Optional[str]:
        """SYNC loss: none for ``sync_timeout`` s (before the first: ``state_timeout`` as well)."""
        since = self._sync_expected_since
        if since is None or not any(d.operational for d in self._drives):
            return None
        limit = self.config.sync_timeout
        age = self.sync_watch.age_s()
        if age is None:
            age, limit = now - since, max(limit, self.config.state_timeout)
        else:
            age = min(age, now - since)
        if age <= limit:
            return None
        who = ("this master's SYNC producer" if self.config.sync_producer == "master"
               else "the external SYNC producer")
        return (f"SYNC lost: no SYNC (COB-ID 0x{SYNC_COB_ID:02X}) for {age * 1000.0:.0f} ms "
                f"(sync_timeout {limit * 1000.0:.0f} ms, {who}); the drives latch no setpoint")

    def _envelope(self, d: _Drive) -> Optional[str]:
        """The joint's position / velocity envelope (config), judged on the latest TPDOs."""
        cfg, fb = d.cfg, d.feedback
        if not d.tpdo_seen or (cfg.position_limits is None and cfg.velocity_limit is None):
            return None
        lo, hi = cfg.position_limits if cfg.position_limits is not None else (-math.inf, math.inf)
        vmax = cfg.velocity_limit if cfg.velocity_limit is not None else math.inf
        inside = lo <= fb.position <= hi and abs(fb.velocity) <= vmax
        if not d.envelope_armed:
            d.envelope_armed = inside       # re-armed once the joint is back inside
            return None
        if not lo <= fb.position <= hi:
            return (f"position envelope: {cfg.name} at {fb.position:.4f} rad, outside "
                    f"[{lo:g}, {hi:g}] rad")
        if abs(fb.velocity) > vmax:
            return (f"velocity envelope: {cfg.name} at {fb.velocity:.3f} rad/s, above "
                    f"{vmax:g} rad/s")
        return None

    def _make_emcy_cb(self, d: _Drive) -> Callable[[Any], None]:
        def on_emcy(err: Any) -> None:
            code = int(err.code)
            if code & 0xFF00 == 0:
                d.emcy.append(f"0x{code:04X} error reset")
                return
            info = describe(code)
            text = (f"EMCY from node {d.node_id} ({d.cfg.name}): code 0x{code:04X} {info.text} "
                    f"({'warning' if info.warning else 'error'}), error register "
                    f"0x{int(err.register):02X}")
            if info.warning:            # the drive keeps operating: report, do not latch
                d.warnings.append(text)
                self.events.append((self.clock(), text))
                log.warning("%s", text)
                return
            d.emcy.append(text)
            d.history_wanted = True
            self.trip(text)
        return on_emcy

    def _make_heartbeat_cb(self, d: _Drive) -> Callable[[int, bytearray, float], None]:
        def on_heartbeat(can_id: int, data: bytearray, timestamp: float) -> None:
            if not data:
                return
            now = self.clock()
            code = data[0] & 0x7F
            d.nmt_state = NMT_STATES.get(code, f"0x{code:02X}")
            if code == 0x00:
                d.boot_count += 1
                d.last_boot = now
                if d.operational:
                    d.operational = False
                    self.trip(f"node {d.node_id} ({d.cfg.name}) rebooted (boot-up frame) while "
                              "in operation; configure again")
                return
            d.last_heartbeat = now
            if code == 0x05:
                d.seen_operational = True
            elif d.operational and d.seen_operational and code in (0x04, 0x7F):
                d.operational = False
                self.trip(f"node {d.node_id} ({d.cfg.name}) left OPERATIONAL (heartbeat reports "
                          f"{d.nmt_state}); configure again")
        return on_heartbeat

    def add_fault_listener(self, listener: Callable[[str], None]) -> None:
        """Call ``listener(reason)`` (on the thread that latched) once the safe state's
        zero-current reaction has been sent."""
        self._fault_listeners.append(listener)

    def remove_fault_listener(self, listener: Callable[[str], None]) -> None:
        """Stop calling ``listener`` (no error if it was not added)."""
        if listener in self._fault_listeners:
            self._fault_listeners.remove(listener)

    def trip(self, reason: str) -> Optional[str]:
        """Latch the safe state with ``reason`` (first reason wins) and react; returns it if new."""
        if self.guard.latch(reason):
            self._react(reason)
            return reason
        if not self.events or self.events[-1][1][:40] != f"also: {reason}"[:40]:
            self.events.append((self.clock(), f"also: {reason}"))
        return None

    def _react(self, reason: str) -> None:
        t_latch = self.clock()
        self.reset_epoch_ns = max(self.reset_epoch_ns, time.time_ns())
        for d in self._drives:
            state = d.feedback.state
            d.target = State.QUICK_STOP_ACTIVE if state is State.OPERATION_ENABLED else State.SWITCH_ON_DISABLED
        self._gate_changed()              # an external player stops sending before the reaction
        log.error("safe state: %s", reason)
        for d in self._drives:
            state = d.feedback.state
            if d.operational:
                cw = (cia402.CONTROLWORD[cia402.Command.QUICK_STOP]
                      if d.target is State.QUICK_STOP_ACTIVE
                      else cia402.CONTROLWORD[cia402.Command.DISABLE_VOLTAGE])
                self._send_rpdo(d, cw, 0)
                if self.config.synchronous and not self._sync_fresh():
                    # a synchronous RPDO takes effect at the next SYNC only: with SYNC gone the
                    # controlword goes as an SDO write too (applied on receipt)
                    self._send_sdo_controlword(d, cw)
        # stamped at the latch, listed once the zero-current reaction has been sent: whoever
        # sees the event also sees applied_currents() == 0
        self.events.append((t_latch, f"safe state: {reason}"))
        for listener in list(self._fault_listeners):
            try:
                listener(reason)
            except Exception:  # noqa: BLE001 - one failing listener must not stop the others
                log.exception("fault listener failed")

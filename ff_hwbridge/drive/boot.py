"""Boot-up and configuration of each drive (the master's SDO side): NMT reset communication and
the wait for the boot-up frame, identity check, 0x6040 = 0 first, mode of operation (EPOS4 10 =
CST, EPOS2 -3 = current mode), heartbeat producer 0x1017 and consumer 0x1016, the drive's own
reactions (0x605A, 0x605E, 0x6007, 0x1029), motor data (checked, read or written), PDO mapping
(RPDO1 type 1 in sync / 255 on receipt; TPDO1/TPDO2 every ``feedback_every`` SYNC, COB-ID bit 30 as
maxon's EDS), 0x60C2 = the SYNC period, NMT start; the object dictionary (built in or an EDS
checked against it), the error history (0x1003 / 0x603F) and disarming 0x1016 on a clean exit."""
from __future__ import annotations

import logging
import math
import time
from typing import Any, Callable, Optional, Sequence

import canopen

from ff_hwbridge.drive.feedback import SamplePairing
from ff_hwbridge.drive.node import (ABORT_NO_OBJECT, OPTIONAL_SUBS, EposError, MasterBase, _Drive)
from ff_hwbridge.protocol.cia402 import State
from ff_hwbridge.protocol.epos_errors import describe
from ff_hwbridge.protocol.epos_od import (DEVICE_PROFILE_402, MAXON_VENDOR_ID, RPDO_SETPOINT, TPDO_MOTION,
                                          TPDO_STATUS, VELOCITY_UNIT_RPM, build_object_dictionary,
                                          rpdo_layout, tpdo1_layout, tpdo2_layout)
from ff_hwbridge.protocol.units import DriveUnits

log = logging.getLogger("ff_hwbridge.drive.epos")

__all__ = ["Boot"]


class Boot(MasterBase):
    """EposMaster's part: configure and set up each drive over SDO."""

    def _configure_drive(self, d: _Drive) -> None:
        with self._sdo_lock:
            self._configure_drive_locked(d)

    def _await_boot(self, d: _Drive) -> None:
        """NMT reset communication until a boot-up frame arrives (one every ``boot_timeout`` s,
        ``boot_wait`` s in all): a drive powered late is waited for. EposError when none came."""
        node, nid = d.node, d.node_id
        t0 = self.clock()
        total = max(self.config.boot_wait, self.config.boot_timeout)
        attempt = 0
        while True:
            attempt += 1
            boots = d.boot_count
            node.nmt.send_command(0x82)     # reset communication
            deadline = min(self.clock() + self.config.boot_timeout, t0 + total)
            while d.boot_count == boots and self.clock() < deadline:
                time.sleep(0.002)
            if d.boot_count != boots:
                if attempt > 1:
                    log.warning("node %d (%s) booted after %.1f s (%d NMT resets)", nid,
                                d.cfg.name, self.clock() - t0, attempt)
                return
            if self.clock() >= t0 + total:
                raise EposError(f"node {nid} ({d.cfg.name}): no boot-up frame within {total:g} s "
                                f"({attempt} NMT reset communication(s), one every "
                                f"{self.config.boot_timeout:g} s); check the node id, bitrate, "
                                "wiring / the drive is powered")
            log.warning("node %d (%s): no boot-up frame yet; waiting for the drive (%.1f of %.1f s, "
                        "NMT reset %d)", nid, d.cfg.name, self.clock() - t0, total, attempt)

    def _configure_drive_locked(self, d: _Drive) -> None:
        node, nid, fam = d.node, d.node_id, d.units.family
        d.operational = False
        d.last_heartbeat = None
        d.notes = []
        if self.config.reset_communication:
            self._await_boot(d)

        def sdo_write(index: int, sub: Optional[int], value: int, what: str) -> None:
            try:
                obj = node.sdo[index] if sub is None else node.sdo[index][sub]
                obj.raw = value
            except Exception as exc:  # noqa: BLE001 - canopen raises SdoError, KeyError, CanError
                raise EposError(f"node {nid} ({d.cfg.name}): SDO write {what} = {value} failed: "
                                f"{exc}") from exc

        def sdo_read(index: int, sub: Optional[int], what: str) -> int:
            try:
                obj = node.sdo[index] if sub is None else node.sdo[index][sub]
                return int(obj.raw)
            except Exception as exc:  # noqa: BLE001
                raise EposError(f"node {nid} ({d.cfg.name}): SDO read {what} failed: {exc}") from exc

        def optional(index: int, sub: Optional[int], value: Optional[int], what: str,
                     quiet: bool = False) -> Optional[int]:
            """Write ``value`` (or read, when None); None when the drive has no such object
            (noted in the diagnostics; logged as a warning unless ``quiet``), EposError on any
            other failure."""
            try:
                obj = node.sdo[index] if sub is None else node.sdo[index][sub]
                if value is None:
                    return int(obj.raw)
                obj.raw = value
                return value
            except canopen.SdoAbortedError as exc:
                if exc.code not in ABORT_NO_OBJECT:
                    raise EposError(f"node {nid} ({d.cfg.name}): SDO {what} failed: {exc}") from exc
            except KeyError:
                pass                   # not in the drive's EDS (the object dictionary used)
            note = f"{what}: not on this drive"
            d.notes.append(note)
            log.log(logging.INFO if quiet else logging.WARNING, "node %d (%s): %s", nid, d.cfg.name, note)
            return None

        if self.config.check_identity:
            dev = sdo_read(0x1000, None, "0x1000 device type")
            if dev & 0xFFFF != DEVICE_PROFILE_402:
                raise EposError(f"node {nid} ({d.cfg.name}): device type 0x1000 = 0x{dev:08X} is not "
                                f"a CiA 402 drive (profile {dev & 0xFFFF}, expected 402); check the "
                                "node id")
            vendor = sdo_read(0x1018, 1, "0x1018:01 vendor id")
            if vendor != MAXON_VENDOR_ID:
                raise EposError(f"node {nid} ({d.cfg.name}): vendor id 0x1018:01 = 0x{vendor:08X}, "
                                f"not maxon (0x{MAXON_VENDOR_ID:08X}); check the node id, or set "
                                "check_identity: false for another CiA 402 drive")
        # whatever state a previous master left it in: no current (disable voltage, transition
        # 7/9/10/12), before anything else is changed
        sdo_write(0x6040, None, 0x0000, "0x6040 controlword (disable voltage)")
        mode = d.cfg.mode_of_operation
        sdo_write(0x6060, None, mode, "0x6060 modes of operation")
        shown = sdo_read(0x6061, None, "0x6061 modes of operation display")
        if shown != mode:
            raise EposError(f"node {nid}: drive shows mode {shown} after 0x6060 = {mode}; "
                            f"is it an {fam.upper()} in a state that accepts the mode?")
        sdo_write(0x1017, None, self.config.heartbeat_producer_ms, "0x1017 producer heartbeat (ms)")
        consumer = ((self.config.master_node_id << 16) | self.config.master_heartbeat_timeout_ms
                    if self.config.master_heartbeat_ms else 0)
        sdo_write(0x1016, 1, consumer, "0x1016:01 consumer heartbeat time (master)")
        d.consumer_armed = consumer != 0
        # the drive's own reactions, explicitly (never the factory settings by accident)
        c = self.config
        for index, sub, value, what in ((0x605A, None, c.quick_stop_option, "0x605A quick stop option"),
                                        (0x605E, None, c.fault_reaction_option, "0x605E fault reaction option"),
                                        (0x6007, None, c.abort_connection_option,
                                         "0x6007 abort connection option"),
                                        (0x1029, 1, c.communication_error_behaviour,
                                         "0x1029:01 communication error behaviour")):
            optional(index, sub, value, what)
        self._apply_scaling(d, sdo_read, sdo_write, optional)
        try:
            # synchronous (1): the drive latches the setpoint at the next SYNC; 255: on receipt
            self._map_pdo(node.rpdo[RPDO_SETPOINT], 0x200 + nid, 1 if c.synchronous else 255,
                          rpdo_layout(fam))
            # the feedback: every feedback_every-th SYNC (transmission type 1..240); TxPDO
            # COB-IDs with bit 30 set (no RTR), as maxon's EDS has them (0x40000180 + id)
            self._map_pdo(node.tpdo[TPDO_STATUS], 0x180 + nid, c.feedback_every, tpdo1_layout(fam),
                          rtr=False)
            self._map_pdo(node.tpdo[TPDO_MOTION], 0x280 + nid, c.feedback_every, tpdo2_layout(fam),
                          rtr=False)
        except Exception as exc:  # noqa: BLE001
            raise EposError(f"node {nid} ({d.cfg.name}): PDO mapping failed: {exc}") from exc
        # CiA 301 RxPDO event timer where a drive has it (maxon's EPOS4 EDS lists none): an
        # extra, nothing relies on it; with synchronous setpoints a hung master is stopped by
        # the drive's interpolation-period supervision (0x60C2: no RPDO in a cycle, EMCY 0x8250)
        if c.rpdo_timeout_ms:
            optional(0x1400, 5, c.rpdo_timeout_ms, "0x1400:05 RxPDO1 event timer (optional)", quiet=True)
        # 0x60C2 interpolation time period = the SYNC period: the drive then expects a setpoint
        # RPDO in every SYNC cycle (supervised: EMCY 0x8250). on_receipt is no cycle contract:
        # 0 (off), whatever an earlier master left there
        period_ms = c.sync_period * 1000.0 if c.synchronous else 0.0
        if abs(period_ms - round(period_ms)) < 1e-9 and 0 <= round(period_ms) <= 255:
            if optional(0x60C2, 1, int(round(period_ms)), "0x60C2:01 interpolation time period") is not None:
                optional(0x60C2, 2, -3, "0x60C2:02 interpolation time index")
        # our own fast decoders instead of canopen's per-variable ones
        net = self._connected_network()
        for cob in (0x180 + nid, 0x280 + nid, 0x200 + nid):
            if cob in net.subscribers:
                net.unsubscribe(cob)
        net.subscribe(0x180 + nid, self._make_tpdo1_cb(d))
        net.subscribe(0x280 + nid, self._make_tpdo2_cb(d))
        if self.echo:
            net.subscribe(0x200 + nid, self._make_echo_cb(d))
        d.target = State.SWITCH_ON_DISABLED
        d.rpdo.controlword = 0
        d.rpdo.setpoint = 0
        d.seen_operational = False           # a PRE-OP heartbeat may still be under way
        d.tpdo_seen = False
        node.nmt.send_command(0x01)          # NMT start -> OPERATIONAL
        d.operational = True
        d.last_heartbeat = self.clock()      # the heartbeat timeout counts from here
        d.pairing = SamplePairing(self.sync_watch.period_ns, c.feedback_every)
        self._publish(d, stamp=self.clock())

    def _apply_scaling(self, d: _Drive, sdo_read: Callable[..., int], sdo_write: Callable[..., None],
                       optional: Callable[..., Optional[int]]) -> None:
        """Motor data: read from the drive and checked against the config (``scaling_source``
        check), taken from the drive (drive, or ``read_motor_data``) or written to it (config);
        then the output current limit. EposError naming both values on disagreement."""
        nid, fam, u = d.node_id, d.units.family, d.units
        src = "drive" if d.cfg.read_motor_data else self.config.scaling_source
        who = f"node {nid} ({d.cfg.name})"
        if fam == "epos2":
            # EPOS2 setpoints are mA: no per-mille base to check
            if src == "drive":
                nom = sdo_read(0x6410, 1, "0x6410:01 continuous current limit (mA)")
                d.units = self._units_from_drive(d, nom, u.torque_constant_raw, u.counts_per_rev)
        else:
            if src == "config":
                sdo_write(0x3001, 1, u.nominal_current_ma, "0x3001:01 nominal current (mA)")
                sdo_write(0x3001, 5, u.torque_constant_raw, "0x3001:05 torque constant (µNm/A)")
                optional(0x6076, None, u.rated_torque_raw, "0x6076 motor rated torque (µNm)")
                optional(0x60A9, None, VELOCITY_UNIT_RPM, "0x60A9 SI unit velocity")
            nom = sdo_read(0x3001, 1, "0x3001:01 nominal current (mA)")
            kt = sdo_read(0x3001, 5, "0x3001:05 torque constant (µNm/A)")
            rated = optional(0x6076, None, None, "0x6076 motor rated torque (µNm)")
            res = optional(0x3000, 5, None, "0x3000:05 main sensor resolution (inc/rev)")
            vel = optional(0x60A9, None, None, "0x60A9 SI unit velocity")
            if vel is not None and vel != VELOCITY_UNIT_RPM:
                raise EposError(f"{who}: velocity unit 0x60A9 = 0x{vel:08X}, the bridge reads 0x606C "
                                f"in rpm (0x{VELOCITY_UNIT_RPM:08X}); set it on the drive or use "
                                "scaling_source: config")
            # the drive's per-mille base: I = ‰/1000 · 0x6076 / 0x3001:05
            base_ma = rated * 1000.0 / kt if rated and kt else float(nom)
            if src == "drive":
                d.units = self._units_from_drive(d, base_ma, kt, res or u.counts_per_rev)
            else:
                tol = self.config.scaling_tolerance
                checks = [("nominal current 0x3001:01", nom / 1000.0, u.nominal_current,
                           "units.nominal_current", "A"),
                          ("torque constant 0x3001:05", kt * 1e-6, u.torque_constant,
                           "units.torque_constant", "Nm/A"),
                          ("per-mille base 0x6076/0x3001:05", base_ma / 1000.0, u.nominal_current,
                           "units.nominal_current", "A")]
                if res:
                    checks.append(("encoder resolution 0x3000:05", float(res), u.counts_per_rev,
                                   "units.counts_per_rev", "inc/rev"))
                bad = [f"{what}: drive {dv:.6g} {unit}, config {key} {cv:.6g} {unit} "
                       f"({(dv - cv) / cv * 100.0:+.1f} %)"
                       for what, dv, cv, key, unit in checks if abs(dv - cv) > tol * abs(cv)]
                if bad:
                    raise EposError(f"{who}: motor data on the drive disagree with the config "
                                    f"(tolerance {tol * 100.0:g} %): " + "; ".join(bad)
                                    + "; fix the config or the drive, or set scaling_source: drive "
                                    "(use the drive's) or config (write the config's)")
        d.rpdo.raw_limit = d.units.setpoint_limit(d.cfg.current_limit)
        if d.cfg.write_current_limit:
            lim_ma = int(math.floor(d.cfg.current_limit * 1000.0))
            if fam == "epos4":
                sdo_write(0x3001, 2, lim_ma, "0x3001:02 output current limit (mA)")
            else:
                sdo_write(0x6410, 2, lim_ma, "0x6410:02 output current limit (mA)")

    @staticmethod
    def _units_from_drive(d: _Drive, nominal_ma: float, kt: int, counts: float) -> DriveUnits:
        try:
            return DriveUnits.from_drive_objects(d.units.family, nominal_ma, kt, counts,  # type: ignore[arg-type]
                                                 d.units.gear_ratio, d.units.direction)
        except ValueError as exc:
            raise EposError(f"node {d.node_id}: motor data read from the drive is unusable: {exc}") from exc

    @staticmethod
    def _map_pdo(pdo_map: Any, cob_id: int, trans_type: int, layout: Sequence[tuple[int, int, str]],
                 rtr: bool = True) -> None:
        """Standard remap over SDO: disable (COB-ID bit 31), count 0, entries, count, enable;
        ``rtr`` False: COB-ID bit 30 set (CiA 301: no RTR allowed on this TPDO)."""
        pdo_map.clear()
        for index, sub, _ in layout:
            pdo_map.add_variable(index, sub)
        pdo_map.cob_id = cob_id
        pdo_map.rtr_allowed = rtr
        pdo_map.trans_type = trans_type
        pdo_map.enabled = True
        pdo_map.save()

    @staticmethod
    def _object_dictionary(d: _Drive) -> Any:
        """The master's object dictionary of a drive: built in, or read from the joint's EDS/DCF
        (canopen.import_od) and checked to hold every object and sub-index the master uses."""
        built = build_object_dictionary(d.units.family, d.node_id)
        if d.cfg.eds is None:
            return built
        try:
            od = canopen.import_od(d.cfg.eds, d.node_id)
        except Exception as exc:  # noqa: BLE001 - any parse error is the file's
            raise EposError(f"node {d.node_id} ({d.cfg.name}): cannot read the EDS {d.cfg.eds!r}: {exc}") from exc
        missing = []
        for obj in built.values():
            if obj.index not in od:
                missing.append(f"0x{obj.index:04X}")
                continue
            subs = getattr(obj, "subindices", None)
            if subs:
                have = od[obj.index]
                missing += [f"0x{obj.index:04X}:{k:02X}" for k in subs
                            if k not in getattr(have, "subindices", {}) and (obj.index, k) not in OPTIONAL_SUBS]
        if missing:
            raise EposError(f"node {d.node_id} ({d.cfg.name}): the EDS {d.cfg.eds!r} lacks object(s) the "
                            f"master uses: {', '.join(missing[:12])}" + (" ..." if len(missing) > 12 else ""))
        return od

    def disarm_heartbeat_consumers(self) -> list[str]:
        """Write 0x1016:01 = 0 on every drive this master armed to consume its heartbeat (while
        that heartbeat still runs); returns the joints where it failed (logged, never raised:
        a drive that cannot be reached faults 0x8130 as it would for a dead master)."""
        failed = []
        if self.network is None or self._bus_lost_told:
            return [d.cfg.name for d in self._drives if d.consumer_armed]
        for d in self._drives:
            if not d.consumer_armed or d.node is None:
                continue
            try:
                with self._sdo_lock:
                    d.node.sdo[0x1016][1].raw = 0
                d.consumer_armed = False
            except Exception as exc:  # noqa: BLE001 - canopen raises SdoError, CanError, ...
                failed.append(d.cfg.name)
                log.warning("node %d (%s): could not disarm its heartbeat consumer 0x1016:01 (%s); "
                            "it faults 0x8130 once this master's heartbeat stops", d.node_id,
                            d.cfg.name, exc)
        return failed

    def read_error_history(self, joint: str) -> str:
        """Read a drive's error history (0x1003, newest first) and error code (0x603F) over SDO,
        decoded with maxon's error table; kept for the diagnostics and listed in ``events``."""
        d = next(x for x in self._drives if x.cfg.name == joint)
        try:
            with self._sdo_lock:
                n = int(d.node.sdo[0x1003][0].raw)
                codes = [int(d.node.sdo[0x1003][i].raw) for i in range(1, min(n, 8) + 1)]
                now_code = int(d.node.sdo[0x603F].raw)
        except Exception as exc:  # noqa: BLE001 - a report, never a reason to stop
            text = f"error history of node {d.node_id} not readable: {exc}"
        else:
            hist = ", ".join(str(describe(c)) for c in codes) or "empty"
            text = (f"node {d.node_id} ({d.cfg.name}) error code 0x603F: {describe(now_code)}; "
                    f"error history 0x1003: {hist}")
        d.error_history = text
        self.events.append((self.clock(), text))
        log.warning("%s", text)
        return text

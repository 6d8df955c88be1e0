"""A minimal in-process EPOS stand-in on canopen's LocalNode, for master tests without the simulator."""
from __future__ import annotations

import struct
import threading
import time

import can
import canopen

from ff_hwbridge.protocol import cia402
from ff_hwbridge.protocol.cia402 import State
from ff_hwbridge.protocol.epos_od import build_object_dictionary
from ff_hwbridge.protocol.units import DriveUnits
from tests.support.canopen_helpers import open_network

FMT = {0x6040: "H", 0x6041: "H", 0x6071: "h", 0x2030: "h", 0x6064: "i", 0x606C: "i",
       0x30D1: "i", 0x6078: "h"}


class MiniEpos:
    """A minimal CiA 402 drive on a canopen LocalNode (test stand-in)."""

    def __init__(self, channel: str, node_id: int, units: DriveUnits) -> None:
        self.units = units
        self.family = units.family
        self.bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.net = open_network(channel, bus=self.bus)
        self.node = canopen.LocalNode(node_id, build_object_dictionary(units.family, node_id, units))
        self.net.add_node(self.node)
        self.id = node_id
        self.state = State.SWITCH_ON_DISABLED
        self.cw = 0
        self.setpoint_raw = 0
        self.position = 0
        self.rpm = 0
        self.answer_sync = True
        self.drop_rx = False
        self.rx_log: list[tuple[int, int]] = []           # (controlword, raw setpoint) per RPDO
        self.rx_wall_ns: list[int] = []                   # time.time_ns() at each RPDO's arrival
        self.sync_pending: list[tuple[bytes, int]] = []   # synchronous RPDOs waiting for SYNC
        self.rpdo_type = 255
        self.transitions: list[int] = []
        self.lock = threading.Lock()
        self.dirty = False
        self.node.add_write_callback(self._on_write)
        self.net.subscribe(0x000, self._on_nmt)
        self.net.subscribe(0x080, self._on_sync)
        self._reload()
        self.node.nmt.send_command(0x82)    # boot: INITIALISING -> boot-up frame
        self.node.nmt.send_command(0x80)    # -> PRE-OPERATIONAL

    def _mapping(self, map_index: int) -> list[tuple[int, int]]:
        n = int(self.node.sdo[map_index][0].raw)
        out = []
        for i in range(1, n + 1):
            e = int(self.node.sdo[map_index][i].raw)
            out.append((e >> 16, (e >> 8) & 0xFF))
        return out

    def _reload(self) -> None:
        with self.lock:
            self.rpdo_map = self._mapping(0x1600)
            self.tpdo1_map = self._mapping(0x1A00)
            self.tpdo2_map = self._mapping(0x1A01)
            self.rpdo_cob = int(self.node.sdo[0x1400][1].raw)
            self.rpdo_type = int(self.node.sdo[0x1400][2].raw)
            self.tpdo_cobs = [int(self.node.sdo[0x1800][1].raw), int(self.node.sdo[0x1801][1].raw)]
        if 0x200 + self.id in self.net.subscribers:
            self.net.unsubscribe(0x200 + self.id)
        self.net.subscribe(0x200 + self.id, self._on_rpdo)

    def _on_write(self, index: int, subindex: int, od, data: bytes) -> None:
        if index in (0x1400, 0x1600, 0x1800, 0x1801, 0x1A00, 0x1A01):
            self.dirty = True        # reloaded lazily: the value is stored after this callback
        if index == 0x6060:
            self.node.data_store.setdefault(0x6061, {})[0] = bytes(data)

    def _on_nmt(self, can_id: int, data: bytes, ts: float) -> None:
        cmd, nid = data[0], data[1]
        if nid in (0, self.id) and cmd in (0x81, 0x82):
            self.node.nmt.send_command(0x82)
            self.node.nmt.send_command(0x80)

    def maps(self) -> None:
        """Reload the PDO maps if the master wrote PDO objects (the drive's duty)."""
        if self.dirty:
            self.dirty = False
            self._reload()

    def _on_rpdo(self, can_id: int, data: bytes, ts: float) -> None:
        arrived = time.time_ns()
        self.maps()
        if self.drop_rx:
            return
        if self.node.nmt.state != "OPERATIONAL" or self.rpdo_cob & 0x80000000:
            return
        if self.rpdo_type <= 240:            # synchronous: latched at the next SYNC
            self.sync_pending.append((bytes(data), arrived))
            return
        self._take(data, arrived)

    def _take(self, data: bytes, arrived: int) -> None:
        fmt = "<" + "".join(FMT[i] for i, _ in self.rpdo_map)
        vals = struct.unpack_from(fmt, data)
        rec = dict(zip([i for i, _ in self.rpdo_map], vals))
        cw = rec.get(0x6040, self.cw)
        cmd = cia402.decode_controlword(cw, self.cw)
        self.cw = cw
        if cmd is not None:
            t = cia402.apply_command(self.state, cmd)
            if t is not None:
                self.state = t.target
                self.transitions.append(t.number)
        sp = rec.get(0x6071, rec.get(0x2030, 0))
        self.setpoint_raw = sp if self.state is State.OPERATION_ENABLED else 0
        self.rx_log.append((cw, sp))
        self.rx_wall_ns.append(arrived)

    def _on_sync(self, can_id: int, data: bytes, ts: float) -> None:
        if self.node.nmt.state != "OPERATIONAL":
            return
        pending, self.sync_pending = self.sync_pending, []
        for data_, arrived in pending:
            self._take(data_, arrived)
        if not self.answer_sync:
            return
        self.maps()
        self.rpm = int(self.setpoint_raw)                    # trivial "physics"
        self.position += self.rpm
        cur_ma = int(round(self.units.setpoint_to_amps(self.setpoint_raw) * 1000))
        values = {0x6041: cia402.encode_statusword(self.state), 0x6064: self.position,
                  0x606C: self.rpm, 0x30D1: cur_ma, 0x6078: cur_ma}
        for cob, mapping in zip(self.tpdo_cobs, (self.tpdo1_map, self.tpdo2_map)):
            if cob & 0x80000000 or not mapping:
                continue
            fmt = "<" + "".join(FMT[i] for i, _ in mapping)
            self.net.send_message(cob & 0x7FF, struct.pack(fmt, *[values[i] for i, _ in mapping]))

    # fault injection
    def raise_fault(self, code: int = 0x2310) -> None:
        self.node.emcy.send(code, 0x01)
        self.state = State.FAULT
        self.setpoint_raw = 0

    def stop_heartbeat(self) -> None:
        self.node.nmt.stop_heartbeat()

    def close(self) -> None:
        self.node.nmt.stop_heartbeat()
        self.net.disconnect()

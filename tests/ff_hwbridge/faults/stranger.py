"""A CiA 402 master as a stranger would write it: the ``canopen`` library alone (``BaseNode402``
with the EPOS4 EDS), no code of the suite. It sets up and drives one EPOS4 in cyclic synchronous
torque mode over a CAN bus given as python-can arguments, checking what it sees on the way.

``run(bus_kwargs, node_id, eds_path)`` returns what it observed (times in s, raw values)."""
from __future__ import annotations

import threading
import time
from typing import Any, Callable

import canopen
from canopen.profiles.p402 import BaseNode402

MASTER_ID = 127                 # the master's own heartbeat node id
HEARTBEAT_S = 0.1               # the master's heartbeat period
CONSUMER_MS = 300               # what the drive allows between two of the master's heartbeats
SYNC_S = 0.01
CST = "CYCLIC SYNCHRONOUS TORQUE"


class _Cycle:
    """The master's cycle, from one user-space thread: SYNC, then RxPDO1 with the values in
    force, every ``period`` s (CiA 402 cyclic synchronous modes: a new target every
    interpolation period; one thread, so every SYNC interval carries one RPDO)."""

    def __init__(self, net: canopen.Network, rpdo: Any, period: float) -> None:
        self._net, self._rpdo, self._period = net, rpdo, period
        self._stop = threading.Event()
        self.cycles = 0
        self._thread = threading.Thread(target=self._run, name="stranger-cycle", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        nxt = time.monotonic()
        while not self._stop.is_set():
            self._net.sync.transmit()
            self._rpdo.transmit()
            self.cycles += 1
            nxt += self._period
            self._stop.wait(max(0.0, nxt - time.monotonic()))

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


def _wait(pred: Callable[[], bool], timeout: float, what: str) -> float:
    t0 = time.monotonic()
    while not pred():
        if time.monotonic() - t0 > timeout:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.005)
    return time.monotonic() - t0


def run(bus_kwargs: dict[str, Any], node_id: int, eds_path: str) -> dict[str, Any]:
    """Identity, CST, PDO remap, enable, torque both ways, quick stop and out of it, 0x6502 /
    0x60C2, then the master's heartbeat stops and the drive must stop by itself."""
    seen: dict[str, Any] = {}
    net = canopen.Network()
    net.connect(**bus_kwargs)
    node = BaseNode402(node_id, eds_path)
    # a shared, loaded machine: generous protocol timeouts
    node.sdo.RESPONSE_TIMEOUT = 3.0
    node.TIMEOUT_SWITCH_STATE_SINGLE = 2.0
    node.TIMEOUT_SWITCH_STATE_FINAL = 4.0
    node.TIMEOUT_CHECK_TPDO = 1.0
    node.TIMEOUT_SWITCH_OP_MODE = 2.0
    net.add_node(node)
    hb: Any = None
    sync: _Cycle | None = None
    try:
        # boot: reset communication, wait for the boot-up frame. The callback is in place before
        # the command: canopen's wait_for_bootup only sees a boot-up that comes after it is
        # called, and a drive can answer before that on a loaded machine
        booted = threading.Event()
        node.nmt.add_heartbeat_callback(lambda state: booted.set() if state == 0 else None)
        node.nmt.send_command(0x82)
        if not booted.wait(10.0):
            raise AssertionError("no boot-up frame within 10 s of the reset communication command")
        sdo = node.sdo
        # identity
        seen["device_type"] = sdo[0x1000].raw
        seen["vendor_id"] = sdo[0x1018][1].raw
        seen["product_code"] = sdo[0x1018][2].raw
        seen["device_name"] = sdo[0x1008].raw
        # the drive's factory reactions
        seen["reactions"] = (sdo[0x605A].raw, sdo[0x605E].raw, sdo[0x6007].raw, sdo[0x1029][1].raw)
        seen["supported_modes"] = sdo[0x6502].raw
        # heartbeat both ways: the drive produces one and consumes the master's
        sdo[0x1017].raw = 50
        node.nmt.wait_for_heartbeat(5.0)
        sdo[0x1016][1].raw = (MASTER_ID << 16) | CONSUMER_MS
        hb = net.send_periodic(0x700 + MASTER_ID, [0x05], HEARTBEAT_S)
        # interpolation time period = the SYNC period (10 ms: value 10, index -3)
        sdo[0x60C2][1].raw = int(SYNC_S * 1000)
        sdo[0x60C2][2].raw = -3
        seen["interpolation"] = (sdo[0x60C2][1].raw, sdo[0x60C2][2].raw)
        # standard PDO remap: RxPDO1 controlword + target torque, TxPDO1 statusword + position,
        # TxPDO2 torque actual + velocity, both on every SYNC
        node.rpdo.read()
        node.tpdo.read()
        r1 = node.rpdo[1]
        r1.clear()
        r1.add_variable(0x6040)
        r1.add_variable(0x6071)
        r1.trans_type = 255
        r1.enabled = True
        t1 = node.tpdo[1]
        t1.clear()
        t1.add_variable(0x6041)
        t1.add_variable(0x6064)
        t1.trans_type = 1
        t1.enabled = True
        t2 = node.tpdo[2]
        t2.clear()
        t2.add_variable(0x6077)
        t2.add_variable(0x606C)
        t2.trans_type = 1
        t2.cob_id = 0x280 + node_id
        t2.enabled = True
        r1.save()
        t1.save()
        t2.save()
        node.setup_402_state_machine(read_pdos=True)
        seen["tpdo1_cob_id"] = sdo[0x1800][1].raw
        # mode CST (BaseNode402 checks 0x6502 first), read back on 0x6061
        node.op_mode = CST
        seen["mode_display"] = sdo[0x6061].raw
        # NMT start, the cycle (SYNC + RxPDO1), the CiA 402 state machine up to OPERATION ENABLED
        node.nmt.state = "OPERATIONAL"
        sync = _Cycle(net, node.rpdo[1], SYNC_S)
        _wait(lambda: 0x6041 in node.tpdo_values and node.tpdo[1].timestamp is not None, 5.0,
              "the first TxPDO1")
        node.rpdo[1]["Target torque"].raw = 0
        node.state = "OPERATION ENABLED"
        seen["enabled"] = node.state

        def torque(per_mille: int) -> None:
            node.rpdo[1]["Target torque"].raw = per_mille
            node.rpdo[1].transmit()

        def values() -> tuple[int, int, int]:
            return (node.tpdo_values[0x6064], node.tpdo_values[0x606C], node.tpdo_values[0x6077])

        # torque both ways: the arm accelerates the way of the torque
        p0 = values()[0]
        torque(300)
        _wait(lambda: values()[2] == 300 and values()[1] > 0, 10.0, "positive speed at +300 ‰")
        time.sleep(0.3)
        seen["positive"] = (values()[0] - p0, values()[1], values()[2])
        torque(-300)
        _wait(lambda: values()[2] == -300 and values()[1] < 0, 10.0, "negative speed at -300 ‰")
        seen["negative_speed"] = values()[1]
        # quick stop (transition 11); the drive's 0x605A decides how it stops and where it stays
        node.state = "QUICK STOP ACTIVE"
        seen["quick_stop_to_standstill_s"] = _wait(
            lambda: values()[1] == 0 and values()[2] == 0, 10.0, "standstill after quick stop")
        time.sleep(0.1)
        seen["state_after_quick_stop"] = node.state
        # the CiA 402 way out: disable voltage (transition 12), then 2, 3, 4
        node.state = "SWITCH ON DISABLED"
        seen["after_disable_voltage"] = node.state
        node.state = "OPERATION ENABLED"
        seen["re_enabled"] = node.state
        torque(100)
        _wait(lambda: values()[2] == 100, 10.0, "torque after re-enable")
        seen["torque_after_re_enable"] = values()[2]
        # the master's heartbeat stops: the drive must stop driving by itself
        node.emcy.reset()
        t_stop = time.monotonic()
        hb.stop()
        hb = None
        err = node.emcy.wait(0x8130, timeout=3.0)
        seen["heartbeat_emcy"] = None if err is None else err.code
        seen["heartbeat_emcy_after_s"] = time.monotonic() - t_stop
        sync.stop()
        sync = None
        _wait(lambda: sdo[0x6077].raw == 0, 10.0, "zero torque after the heartbeat stopped")
        seen["statusword_after_heartbeat_loss"] = sdo[0x6041].raw
        seen["error_code_after_heartbeat_loss"] = sdo[0x603F].raw
        node.nmt.wait_for_heartbeat(2.0)
        seen["nmt_after_heartbeat_loss"] = node.nmt.state
        return seen
    finally:
        if hb is not None:
            hb.stop()
        if sync is not None:
            sync.stop()
        net.disconnect()

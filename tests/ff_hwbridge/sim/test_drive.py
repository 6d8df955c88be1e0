"""The emulated EPOS as a CANopen slave, driven by a plain canopen RemoteNode / raw frames
on an in-process virtual bus."""
from __future__ import annotations

import itertools
import struct
import time

import canopen
import pytest
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from ff_hwbridge.protocol.cia402 import State
from ff_hwbridge.protocol.epos_od import SUPPORTED_MODES, VELOCITY_UNIT_RPM
from ff_hwbridge.sim.arm import SimArm
from ff_hwbridge.sim.drive import (SUPERVISION_SLACK_NS, DriveConfig, SimConfigError, SimEpos,
                                  build_object_dictionary)
from ff_planner.model.params import Arm1DofParams, default_params
from tests.support.canopen_helpers import open_network, waiter

_chan = itertools.count()


wait_for = waiter(3.0)


class Rig:
    """Drive on one canopen Network, master (RemoteNode + frame recorder) on another."""

    def __init__(self, family="epos4", node_id=1, plant=None, **cfg):
        chan = f"test-sim-epos-{next(_chan)}"
        self.cfg = DriveConfig(node_id=node_id, family=family, **cfg)
        self.net_s, self.net_m = open_network(chan), open_network(chan)
        self.frames: list[tuple[float, int, bytes]] = []
        self.net_m.notifier.add_listener(self)  # records every frame the master sees
        self.drive = SimEpos(self.cfg, plant)
        self.drive.attach(self.net_s)
        self.node = canopen.RemoteNode(node_id, build_object_dictionary(self.cfg))
        self.node.sdo.RESPONSE_TIMEOUT = 2.0         # generous: the machine is shared
        self.net_m.add_node(self.node)

    # can.Listener protocol
    def on_message_received(self, msg):
        self.frames.append((time.monotonic(), msg.arbitration_id, bytes(msg.data)))

    __call__ = on_message_received

    def stop(self):
        pass

    def on_error(self, exc):
        pass

    def seen(self, can_id):
        return [d for _, i, d in self.frames if i == can_id]

    def configure_contract_pdos(self):
        n, sp = self.node, (0x6071 if self.cfg.family == "epos4" else 0x2030)
        cur = (0x30D1, 2) if self.cfg.family == "epos4" else (0x6078, 0)
        n.rpdo.read()
        n.tpdo.read()
        r = n.rpdo[1]
        r.clear(); r.add_variable(0x6040); r.add_variable(sp); r.trans_type = 255; r.enabled = True
        t1 = n.tpdo[1]
        t1.clear(); t1.add_variable(0x6041); t1.add_variable(0x6064); t1.trans_type = 1; t1.enabled = True
        t2 = n.tpdo[2]
        t2.clear(); t2.add_variable(0x606C); t2.add_variable(*cur); t2.trans_type = 1; t2.enabled = True
        t2.cob_id = 0x280 + self.cfg.node_id
        n.rpdo[1].save(); n.tpdo[1].save(); n.tpdo[2].save()

    def rpdo(self, cw, sp=0):
        self.net_m.send_message(0x200 + self.cfg.node_id, struct.pack("<Hh", cw, sp))

    def enable(self, mode=None):
        self.node.sdo[0x6060].raw = mode if mode is not None else (10 if self.cfg.family == "epos4" else -3)
        self.node.nmt.send_command(0x01)
        assert wait_for(lambda: self.drive.nmt_state == "OPERATIONAL")
        for cw in (0x06, 0x07, 0x0F):
            self.rpdo(cw)
        assert wait_for(lambda: self.drive.state is State.OPERATION_ENABLED)

    def close(self):
        self.drive.close()
        self.net_m.disconnect()
        self.net_s.disconnect()


@pytest.fixture
def rig():
    r = Rig()
    r.drive.boot()
    yield r
    r.close()


def test_bootup_heartbeat_and_nmt(rig):
    assert wait_for(lambda: rig.seen(0x701) == [b"\x00"])
    assert rig.drive.nmt_state == "PRE-OPERATIONAL"
    rig.node.sdo[0x1017].raw = 10
    assert wait_for(lambda: len(rig.seen(0x701)) >= 4)
    assert rig.seen(0x701)[-1] == b"\x7f"
    rig.node.nmt.send_command(0x01)
    assert wait_for(lambda: rig.seen(0x701)[-1] == b"\x05")
    rig.node.nmt.send_command(0x02)
    assert wait_for(lambda: rig.seen(0x701)[-1] == b"\x04")
    rig.node.nmt.send_command(0x80)
    assert wait_for(lambda: rig.seen(0x701)[-1] == b"\x7f")


def test_reset_node_and_communication(rig):
    rig.node.sdo[0x1017].raw = 10
    rig.node.sdo[0x6060].raw = 10
    rig.frames.clear()
    rig.node.nmt.send_command(0x82)                      # reset communication
    assert wait_for(lambda: b"\x00" in rig.seen(0x701))
    time.sleep(0.05)
    assert rig.seen(0x701) == [b"\x00"]                  # 0x1017 back to 0: no heartbeat
    assert rig.node.sdo[0x6060].raw == 10                # application untouched
    rig.node.nmt.send_command(0x81)                      # reset node
    assert wait_for(lambda: rig.seen(0x701).count(b"\x00") == 2)
    assert rig.node.sdo[0x6060].raw == 0
    assert rig.drive.nmt_state == "PRE-OPERATIONAL"


def test_sdo_motor_data_and_modes(rig):
    sdo = rig.node.sdo
    assert sdo[0x3001][1].raw == 3000                    # mA
    assert sdo[0x3001][2].raw == 10000
    assert sdo[0x3001][5].raw == 26700                   # µNm/A
    assert sdo[0x6076].raw == round(3000 * 26.7)        # µNm = mA · µNm/A / 1000
    assert sdo[0x1018][1].raw == 0xFB
    with pytest.raises(SdoAbortedError) as e:
        sdo[0x6060].raw = 7                              # not an EPOS4 mode
    assert e.value.code == 0x06090030
    sdo[0x6060].raw = 10
    assert sdo[0x6061].raw == 10
    with pytest.raises(SdoAbortedError):
        sdo[0x6041].raw = 1                              # read-only
    with pytest.raises(SdoAbortedError) as e:
        sdo.download(0x6099, 0, b"\x00")
    assert e.value.code == 0x06020000


def test_pdo_remap_is_reloaded_and_guarded(rig):
    rig.configure_contract_pdos()
    d = rig.drive.node
    assert [(v.index, v.subindex) for v in d.rpdo[1].map] == [(0x6040, 0), (0x6071, 0)]
    assert [(v.index, v.subindex) for v in d.tpdo[2].map] == [(0x606C, 0), (0x30D1, 2)]
    assert d.tpdo[2].enabled and d.tpdo[2].cob_id == 0x281 and d.tpdo[2].trans_type == 1
    with pytest.raises(SdoAbortedError) as e:                # PDO valid: mapping locked
        rig.node.sdo[0x1600][0].raw = 0
    assert e.value.code == 0x08000022
    rig.node.sdo[0x1400][1].raw = 0x80000201               # disable
    with pytest.raises(SdoAbortedError) as e:
        rig.node.sdo[0x1600][1].raw = 0x60410010             # count not 0 yet
    rig.node.sdo[0x1600][0].raw = 0
    with pytest.raises(SdoAbortedError) as e:                # statusword is not an RPDO object
        rig.node.sdo[0x1600][1].raw = 0x60410010
    assert e.value.code == 0x06040041


def test_cia402_transitions_by_controlword(rig):
    d, sdo = rig.drive, rig.node.sdo
    sdo[0x6060].raw = 10
    assert d.state is State.SWITCH_ON_DISABLED
    for cw, state in ((0x06, State.READY_TO_SWITCH_ON), (0x07, State.SWITCHED_ON),
                      (0x0F, State.OPERATION_ENABLED), (0x07, State.SWITCHED_ON),
                      (0x0F, State.OPERATION_ENABLED), (0x06, State.READY_TO_SWITCH_ON),
                      (0x0F, State.OPERATION_ENABLED), (0x00, State.SWITCH_ON_DISABLED)):
        sdo[0x6040].raw = cw
        assert d.state is state, (hex(cw), d.state)
        assert sdo[0x6041].raw & 0x6F == {State.READY_TO_SWITCH_ON: 0x21, State.SWITCHED_ON: 0x23,
                                          State.OPERATION_ENABLED: 0x27}.get(state, sdo[0x6041].raw & 0x6F)
    assert d.transitions == [2, 3, 4, 5, 4, 8, 3, 4, 9]
    # quick stop, option 2: current 0, then SWITCH ON DISABLED when stopped (12)
    sdo[0x605A].raw = 2
    for cw in (0x06, 0x0F, 0x02):
        sdo[0x6040].raw = cw
    assert sdo[0x6041].raw & 0x4F == 0x40
    assert d.transitions[-2:] == [11, 12]
    # option 6 (maxon's factory setting): stay in QUICK STOP ACTIVE, enable operation again (16)
    sdo[0x605A].raw = 6
    for cw in (0x06, 0x0F, 0x02):
        sdo[0x6040].raw = cw
    assert d.state is State.QUICK_STOP_ACTIVE and sdo[0x6041].raw & 0x6F == 0x07
    sdo[0x6040].raw = 0x0F
    assert d.state is State.OPERATION_ENABLED and d.transitions[-1] == 16


def test_setpoint_applied_on_arrival_and_clamped(rig):
    rig.configure_contract_pdos()
    rig.enable()
    d = rig.drive
    rig.rpdo(0x0F, 500)                                  # 500 ‰ of 3 A nominal
    assert wait_for(lambda: len(d.setpoint_log()) >= 4 and d.applied_current == pytest.approx(1.5))
    rec = d.setpoint_log()[-1]
    assert rec.raw == 500 and rec.source == "rpdo" and rec.commanded == pytest.approx(1.5)
    assert abs(rec.wall_ns - time.time_ns()) < 5e9 and rec.mono_ns <= time.monotonic_ns()
    rig.rpdo(0x0F, -5000)                                # -15 A asked, limit 10 A
    assert wait_for(lambda: d.applied_current == pytest.approx(-10.0))
    assert d.setpoint_log()[-1].commanded == pytest.approx(-15.0)
    rig.rpdo(0x07, 500)                                  # disable operation: no current
    assert wait_for(lambda: d.state is State.SWITCHED_ON)
    assert d.applied_current == 0.0


def test_no_current_outside_current_mode():
    r = Rig()
    try:
        r.drive.boot()
        r.configure_contract_pdos()
        r.enable(mode=9)                                 # CSV: the sim drives no current
        r.rpdo(0x0F, 500)
        assert wait_for(lambda: len(r.drive.setpoint_log()) >= 4)
        assert r.drive.applied_current == 0.0
        assert not r.node.sdo[0x6041].raw & (1 << 12)
    finally:
        r.close()


def test_epos2_current_mode_in_milliamps():
    r = Rig(family="epos2", node_id=2)
    try:
        r.drive.boot()
        r.configure_contract_pdos()
        assert r.node.sdo[0x6410][2].raw == 10000
        r.enable()
        r.rpdo(0x0F, 2500)                               # mA
        assert wait_for(lambda: r.drive.applied_current == pytest.approx(2.5))
        r.net_m.sync.transmit()
        assert wait_for(lambda: len(r.seen(0x282)) >= 1)
        rpm, ma = struct.unpack("<ih", r.seen(0x282)[-1])
        assert ma == 2500 and rpm == 0
    finally:
        r.close()


class MovingPlant:
    """Stand-in plant: joint at a fixed speed, current echoed."""

    def __init__(self):
        self.i = 0.0

    def set_current(self, current, t_ns):
        self.i = current

    def sample(self, t_ns):
        return 1.0, 0.5, self.i


def test_tpdos_on_sync_only_when_operational():
    r = Rig(plant=MovingPlant(), gear_ratio=54.0, counts_per_rev=4096)
    try:
        r.drive.boot()
        r.configure_contract_pdos()
        r.net_m.sync.transmit()
        time.sleep(0.05)
        assert r.seen(0x181) == []                       # PRE-OPERATIONAL: no PDOs
        r.enable()
        r.rpdo(0x0F, 1000)
        n0 = len(r.seen(0x181))
        for _ in range(3):
            r.net_m.sync.transmit()
        assert wait_for(lambda: len(r.seen(0x181)) == n0 + 3 and len(r.seen(0x281)) == 3)
        sw, pos = struct.unpack("<Hi", r.seen(0x181)[-1])
        rpm, ma = struct.unpack("<ii", r.seen(0x281)[-1])
        assert sw & 0x6F == 0x27
        assert pos == round(1.0 * 54 / (2 * 3.141592653589793) * 4096)
        assert rpm == round(0.5 * 54 * 60 / (2 * 3.141592653589793))
        assert ma == 3000
        r.node.nmt.send_command(0x02)                    # STOPPED: no more PDOs
        assert wait_for(lambda: r.drive.nmt_state == "STOPPED")
        n1 = len(r.seen(0x181))
        r.net_m.sync.transmit()
        time.sleep(0.05)
        assert len(r.seen(0x181)) == n1
        r.node.sdo.RESPONSE_TIMEOUT = 0.2
        with pytest.raises(SdoCommunicationError):       # no SDO in STOPPED either
            _ = r.node.sdo[0x6060].raw
    finally:
        r.close()


def test_tpdos_of_transmission_type_n_answer_every_nth_sync():
    r = Rig(plant=MovingPlant(), gear_ratio=54.0, counts_per_rev=4096)
    try:
        r.drive.boot()
        r.configure_contract_pdos()
        for k in (1, 2):
            r.node.tpdo[k].trans_type = 3
            r.node.tpdo[k].save()
        r.enable()
        n1, n2 = len(r.seen(0x181)), len(r.seen(0x281))
        for _ in range(9):
            r.net_m.sync.transmit()
            time.sleep(0.005)
        assert wait_for(lambda: len(r.seen(0x181)) == n1 + 3 and len(r.seen(0x281)) == n2 + 3)
        time.sleep(0.05)
        assert len(r.seen(0x181)) == n1 + 3              # and no more
    finally:
        r.close()


def test_emcy_fault_and_fault_reset(rig):
    rig.configure_contract_pdos()
    rig.enable()
    rig.rpdo(0x0F, 500)
    assert wait_for(lambda: rig.drive.applied_current > 0)
    rig.drive.raise_emcy(0x2310)                         # over-current
    assert wait_for(lambda: len(rig.seen(0x81)) == 1)
    code, reg = struct.unpack_from("<HB", rig.seen(0x81)[0])
    assert code == 0x2310 and reg & 0x03 == 0x03         # generic + current
    assert rig.drive.applied_current == 0.0
    sw = rig.node.sdo[0x6041].raw
    assert sw & 0x4F == 0x08
    assert rig.node.sdo[0x1001].raw == reg
    assert rig.node.sdo[0x1003][1].raw == 0x2310
    rig.rpdo(0x0F, 500)                                  # setpoints ignored while in FAULT
    time.sleep(0.02)
    assert rig.drive.applied_current == 0.0
    rig.rpdo(0x80)                                       # fault reset (rising edge)
    assert wait_for(lambda: rig.drive.state is State.SWITCH_ON_DISABLED)
    assert wait_for(lambda: len(rig.seen(0x81)) == 2)
    assert struct.unpack_from("<HB", rig.seen(0x81)[1]) == (0, 0)
    assert rig.node.sdo[0x1001].raw == 0
    for cw in (0x06, 0x0F):
        rig.rpdo(cw, 500)
    assert wait_for(lambda: rig.drive.applied_current == pytest.approx(1.5))


def test_fault_heartbeat_stop_and_resume(rig):
    rig.node.sdo[0x1017].raw = 10
    assert wait_for(lambda: len(rig.seen(0x701)) >= 3)
    rig.drive.stop_heartbeat()
    time.sleep(0.03)
    n = len(rig.seen(0x701))
    time.sleep(0.1)
    assert len(rig.seen(0x701)) == n
    rig.drive.stop_heartbeat(False)
    assert wait_for(lambda: len(rig.seen(0x701)) >= n + 3)


def test_fault_sdo_silent(rig):
    rig.drive.set_sdo_silent()
    rig.node.sdo.RESPONSE_TIMEOUT = 0.3
    with pytest.raises(SdoCommunicationError):
        _ = rig.node.sdo[0x6060].raw
    rig.drive.set_sdo_silent(False)
    assert rig.node.sdo[0x6060].raw == 0


def test_fault_drop_next_and_fraction(rig):
    rig.configure_contract_pdos()
    rig.enable()
    d = rig.drive
    d.clear_setpoint_log()
    d.drop_next(3)
    for k in range(5):
        rig.rpdo(0x0F, 100 + k)
    assert wait_for(lambda: len(d.setpoint_log()) == 2)
    assert [r.raw for r in d.setpoint_log()] == [103, 104]
    assert d.link_stats.rx_dropped == 3
    d.drop_fraction(1.0)
    rig.rpdo(0x0F, 7)
    time.sleep(0.03)
    assert len(d.setpoint_log()) == 2
    d.clear_injected_faults()
    d.drop_next(2, "tx")                                 # the drive's next 2 frames are lost
    rig.net_m.sync.transmit()                            # TPDO1 + TPDO2 dropped
    rig.net_m.sync.transmit()
    assert wait_for(lambda: len(rig.seen(0x281)) == 1)
    time.sleep(0.02)
    assert len(rig.seen(0x281)) == 1 and d.link_stats.tx_dropped == 2


def test_fault_delay_rx(rig):
    rig.configure_contract_pdos()
    rig.enable()
    d = rig.drive
    d.set_delay(30, "rx")
    t0 = time.monotonic_ns()
    rig.rpdo(0x0F, 321)
    assert wait_for(lambda: d.setpoint_log()[-1].raw == 321)
    assert d.setpoint_log()[-1].mono_ns - t0 >= 29e6      # applied when it "arrived", late
    d.set_delay(0)


def test_bad_settings_are_refused():
    with pytest.raises(SimConfigError, match="node_id"):
        DriveConfig(node_id=0)
    with pytest.raises(SimConfigError, match="family"):
        DriveConfig(family="epos3")
    d = SimEpos(DriveConfig())
    with pytest.raises(SimConfigError, match="fraction"):
        d.drop_fraction(1.5)
    with pytest.raises(SimConfigError, match="direction"):
        d.set_delay(1, "up")
    with pytest.raises(SimConfigError, match="EMCY code"):
        d.raise_emcy(0x10)


def test_heartbeat_consumer_faults_on_a_silent_master(rig):
    rig.configure_contract_pdos()
    rig.node.sdo[0x6007].raw = 1                          # abort connection: fault signal
    rig.node.sdo[0x1029][1].raw = 1                       # NMT state unchanged
    rig.node.sdo[0x1016][1].raw = (127 << 16) | 100      # consume node 127's heartbeat, 100 ms
    task = rig.net_m.send_periodic(0x77F, [0x05], 0.005)
    try:
        rig.enable()
        rig.rpdo(0x0F, 500)
        assert wait_for(lambda: rig.drive.applied_current == pytest.approx(1.5))
        time.sleep(0.1)
        assert rig.drive.state is State.OPERATION_ENABLED  # heartbeats keep coming
    finally:
        task.stop()
    assert wait_for(lambda: rig.drive.state is State.FAULT)
    assert time.monotonic() - rig.drive.heartbeats_seen()[127] >= 0.1     # not before the timeout
    assert rig.drive.applied_current == 0.0
    assert wait_for(lambda: any(d[:2] == b"\x30\x81" for d in rig.seen(0x81)))   # EMCY 0x8130
    rig.node.sdo[0x1016][1].raw = 0                       # consumer off, then fault reset
    rig.rpdo(0x80)
    assert wait_for(lambda: rig.drive.state is State.SWITCH_ON_DISABLED)

    assert rig.node.sdo[0x603F].raw == 0                  # error code cleared by the reset


@pytest.mark.parametrize("option, state", [(0, State.OPERATION_ENABLED), (2, State.SWITCH_ON_DISABLED),
                                           (3, State.QUICK_STOP_ACTIVE)])
def test_communication_error_follows_abort_connection_option(rig, option, state):
    """0x6007: 0 EMCY only (the current goes on), 2 disable voltage, 3 quick stop (maxon's
    default); then 0x1029:01 = 0 (default): PRE-OPERATIONAL."""
    rig.configure_contract_pdos()
    assert rig.node.sdo[0x6007].raw == 3 and rig.node.sdo[0x1029][1].raw == 0   # maxon defaults
    rig.node.sdo[0x605A].raw = 6                          # stay in quick stop active
    rig.node.sdo[0x6007].raw = option
    rig.node.sdo[0x1016][1].raw = (127 << 16) | 60
    task = rig.net_m.send_periodic(0x77F, [0x05], 0.005)
    try:
        rig.enable()
        rig.rpdo(0x0F, 500)
        assert wait_for(lambda: rig.drive.applied_current == pytest.approx(1.5))
    finally:
        task.stop()
    assert wait_for(lambda: any(d[:2] == b"\x30\x81" for d in rig.seen(0x81)))   # EMCY 0x8130
    assert wait_for(lambda: rig.drive.nmt_state == "PRE-OPERATIONAL")
    assert rig.drive.state is state
    assert rig.drive.applied_current == (pytest.approx(1.5) if option == 0 else 0.0)


def test_no_rxpdo_event_timer_as_in_maxons_eds(rig):
    """maxon's EPOS4 EDS has no RxPDO event timer: 0x1400:05 is refused, not silently stored."""
    for index in (0x1400, 0x1401):
        with pytest.raises(SdoAbortedError) as e:
            rig.node.sdo.download(index, 5, struct.pack("<H", 80))
        assert e.value.code == 0x06090011                 # sub-index does not exist
        with pytest.raises(SdoAbortedError) as e:
            rig.node.sdo.upload(index, 5)
        assert e.value.code == 0x06090011
    assert rig.node.sdo.upload(0x1400, 0) == b"\x02"      # highest sub-index: 2


class CstCycle:
    """Frames handed to the drive's network in the calling thread, with chosen bus instants (s,
    wall clock): a master that sends RPDO1 (synchronous, type 1) and a SYNC every ``period``."""

    def __init__(self, rig, period: float = 0.01, ip_ms: int = 10):
        self.rig, self.period = rig, period
        rig.configure_contract_pdos()
        rig.node.rpdo[1].trans_type = 1
        rig.node.rpdo[1].save()
        rig.node.sdo[0x60C2][1].raw = ip_ms
        rig.node.sdo[0x60C2][2].raw = -3
        rig.node.sdo[0x6060].raw = 10
        rig.node.nmt.send_command(0x01)
        assert wait_for(lambda: rig.drive.nmt_state == "OPERATIONAL")
        # bus instants ahead of the wall clock: every frame is handled "on time" (before its
        # bus instant), however slowly this thread runs
        self.t = time.time() + 1.0

    def rpdo(self, cw: int, sp: int = 0, at: float | None = None) -> None:
        t = self.t + self.period / 2 if at is None else at
        self.rig.net_s.notify(0x201, bytearray(struct.pack("<Hh", cw, sp)), t)

    def sync(self) -> None:
        self.t += self.period
        self.rig.net_s.notify(0x80, bytearray(), self.t)

    def cycle(self, cw: int = 0x0F, sp: int = 300) -> None:
        """One cycle: the RPDO, then the SYNC that latches it."""
        self.rpdo(cw, sp)
        self.sync()

    def enable(self) -> None:
        for cw in (0x06, 0x07, 0x0F):
            self.cycle(cw)
        assert self.rig.drive.state is State.OPERATION_ENABLED


def _lag(period_s: float) -> int:
    """SYNCs after an interval at which the drive judges it (``SUPERVISION_SLACK_NS``)."""
    return max(1, -(-SUPERVISION_SLACK_NS // int(round(period_s * 1e9))))


def test_a_sync_interval_without_rpdo_faults_0x8250_in_cst(rig):
    """EPOS4 in CST with 0x60C2 set: a SYNC interval that brings no new target RPDO faults the
    drive (EMCY 0x8250 RPDO timeout, current 0); judged ``_lag`` SYNCs after the interval."""
    c = CstCycle(rig)
    c.enable()
    for _ in range(20):
        c.cycle()
    d = rig.drive
    assert d.state is State.OPERATION_ENABLED and d.applied_current == pytest.approx(0.9)
    for _ in range(_lag(c.period)):                       # the empty interval, not judged yet
        c.sync()
        assert d.state is State.OPERATION_ENABLED
    c.sync()                                              # now it is
    assert d.state is State.FAULT and d.fault_code == 0x8250 and d.interpolation_faults == 1
    assert d.applied_current == 0.0
    assert rig.node.sdo[0x603F].raw == 0x8250 and rig.node.sdo[0x1003][1].raw == 0x8250
    assert wait_for(lambda: any(f[:2] == b"\x50\x82" for f in rig.seen(0x81)))   # EMCY 0x8250


def test_a_target_every_cycle_keeps_the_drive_enabled(rig):
    """500 cycles with an RPDO each, some of them delivered after the next SYNC though on the bus
    before it (a virtual channel's order): no fault. The asynchronous RxPDO (type 255) counts
    too."""
    c = CstCycle(rig)
    c.enable()
    d = rig.drive
    for k in range(500):
        if k % 50 == 7:                                   # on the bus before SYNC, handled after
            at = c.t + c.period / 2
            c.sync()
            c.rpdo(0x0F, 300, at=at)
        else:
            c.cycle()
        assert d.state is State.OPERATION_ENABLED, k
    assert d.applied_current == pytest.approx(0.9)
    rig.node.rpdo[1].trans_type = 255                     # change the map: disable it first
    rig.node.rpdo[1].save()
    for _ in range(50):
        c.cycle()
    assert d.state is State.OPERATION_ENABLED and d.fault_code == 0


def test_enable_again_after_an_interpolation_fault_and_a_reset(rig):
    c = CstCycle(rig)
    c.enable()
    d = rig.drive
    for _ in range(_lag(c.period) + 1):
        c.sync()
    assert d.state is State.FAULT and d.fault_code == 0x8250
    c.cycle(0x80)                                         # fault reset, latched at the SYNC
    assert d.state is State.SWITCH_ON_DISABLED and d.fault_code == 0
    c.enable()
    for _ in range(200):
        c.cycle(0x0F, 500)
    assert d.state is State.OPERATION_ENABLED and d.applied_current == pytest.approx(1.5)


def test_an_interval_opened_by_a_sync_the_bus_delivered_late_is_not_judged(rig):
    """A SYNC handled more than half a period after its bus instant (the simulated bus was late,
    which a real one is not, and the master answering it too): the interval it opens is counted
    as unjudged, not faulted. SYNCs on time again: an empty interval faults as before."""
    c = CstCycle(rig)
    c.t = time.time() - 2.0                               # every frame handled ~2 s late
    c.enable()
    for _ in range(20):
        c.cycle()
    n = 3 * _lag(c.period)
    for _ in range(n):
        c.sync()
    d = rig.drive
    assert d.state is State.OPERATION_ENABLED and d.interpolation_unjudged >= n - _lag(c.period) - 1
    assert d.interpolation_faults == 0
    c.t = time.time() + 1.0                               # on time from here (ahead of the clock)
    for _ in range(_lag(c.period) + 2):
        c.sync()
    assert d.state is State.FAULT and d.fault_code == 0x8250 and d.interpolation_faults == 1


@pytest.mark.parametrize("case", ["option_off", "no_interpolation_period", "not_enabled"])
def test_no_interpolation_supervision_where_it_does_not_apply(case):
    """Off by the simulator's option (tests of old masters), with 0x60C2 = 0 (the factory
    value), or outside OPERATION ENABLED: SYNCs without RPDOs do not fault the drive."""
    r = Rig(interpolation_supervision=case != "option_off")
    r.drive.boot()
    try:
        c = CstCycle(r, ip_ms=0 if case == "no_interpolation_period" else 10)
        if case == "not_enabled":
            c.cycle(0x06)
            c.cycle(0x07)
            want = State.SWITCHED_ON
        else:
            c.enable()
            want = State.OPERATION_ENABLED
        for _ in range(3 * _lag(c.period) + 5):
            c.sync()
        assert r.drive.state is want and r.drive.fault_code == 0
    finally:
        r.close()


def test_interpolation_supervision_on_the_bus_in_real_time(rig):
    """A master thread sending RPDO1 then SYNC every 10 ms over the virtual bus keeps the drive
    enabled; SYNC alone (a frozen master whose SYNC goes on) faults it 0x8250."""
    rig.configure_contract_pdos()
    rig.node.rpdo[1].trans_type = 1
    rig.node.rpdo[1].save()
    rig.node.sdo[0x60C2][1].raw = 10
    rig.node.sdo[0x6060].raw = 10
    rig.node.nmt.send_command(0x01)
    assert wait_for(lambda: rig.drive.nmt_state == "OPERATIONAL")
    d = rig.drive
    for cw in (0x06, 0x07, 0x0F):
        rig.rpdo(cw, 0)
        rig.net_m.sync.transmit()
    assert wait_for(lambda: d.state is State.OPERATION_ENABLED)
    t_end = time.monotonic() + 1.0
    while time.monotonic() < t_end:
        rig.rpdo(0x0F, 300)
        rig.net_m.sync.transmit()
        time.sleep(0.01)
    assert wait_for(lambda: d.applied_current == pytest.approx(0.9))
    assert d.state is State.OPERATION_ENABLED and d.fault_code == 0
    n_sync = 0
    while d.state is State.OPERATION_ENABLED and n_sync < 200:
        rig.net_m.sync.transmit()
        n_sync += 1
        time.sleep(0.01)
    assert d.state is State.FAULT and d.fault_code == 0x8250
    assert n_sync >= _lag(0.01) + 1                       # not before the interval was judged
    assert d.applied_current == 0.0


def test_warning_emcy_does_not_fault(rig):
    rig.configure_contract_pdos()
    rig.enable()
    rig.rpdo(0x0F, 500)
    assert wait_for(lambda: rig.drive.applied_current == pytest.approx(1.5))
    rig.drive.raise_warning(0xFF01)
    assert wait_for(lambda: any(d[:2] == b"\x01\xFF" for d in rig.seen(0x81)))
    assert rig.drive.state is State.OPERATION_ENABLED
    assert rig.drive.applied_current == pytest.approx(1.5)
    assert rig.node.sdo[0x6041].raw & (1 << 7)            # statusword bit 7: warning
    rig.drive.clear_warning()
    assert not rig.node.sdo[0x6041].raw & (1 << 7)
    rig.rpdo(0x0F, 5000)                                  # 15 A requested, limit 10 A
    assert wait_for(lambda: rig.drive.applied_current == pytest.approx(10.0))
    assert rig.node.sdo[0x6041].raw & (1 << 11)           # internal limit active


def test_epos4_objects_a_stranger_reads():
    """What a CiA 402 master reads from an EPOS4 before it trusts it, with the configured motor
    data and maxon's defaults."""
    r = Rig(nominal_current=2.5, counts_per_rev=4096)
    r.drive.boot()
    try:
        sdo = r.node.sdo
        assert sdo[0x1000].raw & 0xFFFF == 402 and sdo[0x1018][1].raw == 0xFB
        assert sdo[0x6502].raw == SUPPORTED_MODES["epos4"] and sdo[0x6502].raw & (1 << 9)   # CST
        assert (sdo[0x60C2][1].raw, sdo[0x60C2][2].raw) == (0, -3)
        assert sdo[0x603F].raw == 0
        assert (sdo[0x605A].raw, sdo[0x605E].raw, sdo[0x6007].raw, sdo[0x1029][1].raw) == (6, 2, 3, 0)
        assert sdo[0x6085].raw == 10000
        assert sdo[0x3000][5].raw == 4096
        assert sdo[0x60A9].raw == VELOCITY_UNIT_RPM
        assert sdo[0x3001][1].raw == 2500 and sdo[0x3001][5].raw == 26700
        assert sdo[0x6076].raw == 2500 * 26700 // 1000
    finally:
        r.close()


def _sdo_latency_after_idle(node, idle: float) -> float:
    time.sleep(idle)
    t0 = time.perf_counter()
    _ = node.sdo[0x6064].raw                              # a live object: samples the plant
    return time.perf_counter() - t0


def test_physics_runs_on_its_own_clock_not_in_the_can_thread():
    """The plant advances on its own thread: the first SDO after an idle spell answers as fast
    as after a short one (no catch-up integration inside the CAN callback)."""
    params = default_params("arm1dof")
    arm = SimArm(params, 0.0)
    arm.start_clock(0.002)
    r = Rig(plant=arm.port(0))
    r.drive.boot()
    try:
        r.enable()
        r.rpdo(0x0F, 300)                                 # moving: every step has work to do
        short = _sdo_latency_after_idle(r.node, 0.2)
        long = _sdo_latency_after_idle(r.node, 1.0)    # lazy catch-up cost ~40 ms per idle s
        assert long < 0.05, long
        assert long < short + 0.02, (short, long)         # no growth with the idle time
    finally:
        r.close()
        arm.stop_clock()


def _moving_rig(sdo_writes=None, speed: float = 1.5):
    """A drive on the 1-DOF arm (its own clock), enabled in CST, the arm at ``speed`` rad/s."""
    params = default_params("arm1dof")
    assert isinstance(params, Arm1DofParams)
    arm = SimArm(params, 0.0)
    arm.start_clock(0.002)
    r = Rig(plant=arm.port(0), load_inertia=params.J)
    r.drive.boot()
    r.configure_contract_pdos()
    for (index, sub), value in (sdo_writes or {}).items():
        (r.node.sdo[index] if sub is None else r.node.sdo[index][sub]).raw = value
    r.enable()
    r.rpdo(0x0F, 1000)                                    # 3 A: at speed within about 0.1 s
    assert wait_for(lambda: arm.state().qd[0] > speed, 5.0)
    return r, arm


def test_quick_stop_brakes_on_the_quick_stop_ramp_and_stays_quick_stop_active():
    """CST quick stop with maxon's 0x605A = 6: the drive brakes the motor under its velocity
    loop at 0x6085 (rpm/s of the motor) to standstill, then holds QUICK STOP ACTIVE at 0 A."""
    decel = 3000                                          # rpm/s -> 5.8 rad/s² at the joint
    r, arm = _moving_rig({(0x6085, None): decel})
    try:
        v0 = arm.state().qd[0]
        alpha = decel * 2 * 3.141592653589793 / 60 / r.cfg.gear_ratio
        t0 = time.monotonic()
        r.rpdo(0x02, 300)                                 # quick stop; the setpoint is ignored
        assert wait_for(lambda: r.drive.state is State.QUICK_STOP_ACTIVE)
        assert wait_for(lambda: r.drive.applied_current < -0.5)   # braking, not just 0 A
        time.sleep(0.5 * v0 / alpha)
        mid = arm.state().qd[0]
        assert 0.2 * v0 < mid < 0.8 * v0, (v0, mid)      # on the ramp: neither cut nor coasting
        assert wait_for(lambda: r.drive.applied_current == 0.0 and not r.drive.braking, 5.0)
        t_stop = time.monotonic() - t0
        assert 0.7 * v0 / alpha < t_stop < 3.0 * v0 / alpha + 0.3, (t_stop, v0 / alpha)
        assert wait_for(lambda: abs(arm.state().qd[0]) < 0.01, 2.0)
        assert r.drive.state is State.QUICK_STOP_ACTIVE and r.node.sdo[0x6041].raw & 0x6F == 0x07
    finally:
        r.close()
        arm.stop_clock()


def test_quick_stop_option_2_ends_switch_on_disabled_and_0_cuts_the_current():
    r, arm = _moving_rig({(0x605A, None): 2})
    try:
        r.rpdo(0x02, 300)
        assert wait_for(lambda: r.drive.braking)
        assert wait_for(lambda: r.drive.state is State.SWITCH_ON_DISABLED, 5.0)
        assert r.drive.transitions[-2:] == [11, 12] and r.drive.applied_current == 0.0
    finally:
        r.close()
        arm.stop_clock()
    r, arm = _moving_rig({(0x605A, None): 0})
    try:
        r.rpdo(0x02, 300)
        assert wait_for(lambda: r.drive.state is State.SWITCH_ON_DISABLED)
        # the state is published a moment before the power stage's current: wait for that, then
        # check the drive's own stamps: the current dropped to 0 A at the transition's instant
        assert wait_for(lambda: r.drive.applied_current == 0.0)
        last = r.drive.state_log[-1]
        assert last.transition == 9 and r.drive.zero_current_ns == last.mono_ns   # motor free at once
        assert not r.drive.braking
    finally:
        r.close()
        arm.stop_clock()


@pytest.mark.parametrize("option", [0, 2])
def test_fault_reaction_option(option):
    """0x605E: 0 = disable drive function (current 0 at once, FAULT); 2 = quick stop ramp in
    FAULT REACTION ACTIVE, then FAULT (transition 14) at standstill."""
    r, arm = _moving_rig({(0x605E, None): option})
    try:
        r.drive.raise_emcy(0x2310)
        if option == 0:
            assert r.drive.state is State.FAULT and r.drive.applied_current == 0.0
        else:
            assert r.drive.state is State.FAULT_REACTION_ACTIVE and r.drive.applied_current < 0.0
            assert wait_for(lambda: r.drive.state is State.FAULT, 5.0)
            assert r.drive.applied_current == 0.0
            assert wait_for(lambda: abs(arm.state().qd[0]) < 0.01, 2.0)   # friction: at rest
        assert r.drive.transitions[-1] == 14 and r.node.sdo[0x603F].raw == 0x2310
    finally:
        r.close()
        arm.stop_clock()


def test_event_driven_tpdo_on_change_with_inhibit_and_event_timer(rig):
    """TxPDO1 at transmission type 255 (maxon's default): sent on a change of its statusword
    without any SYNC; with an event timer also periodically."""
    n = rig.node
    n.tpdo.read()
    t1 = n.tpdo[1]
    t1.clear()
    t1.add_variable(0x6041)
    t1.trans_type = 255
    t1.inhibit_time = 20                                  # 2 ms
    t1.enabled = True
    t1.save()
    rig.node.sdo[0x6060].raw = 10
    rig.node.nmt.send_command(0x01)
    assert wait_for(lambda: rig.drive.nmt_state == "OPERATIONAL")
    assert wait_for(lambda: len(rig.seen(0x181)) == 1)   # the present statusword once
    time.sleep(0.1)
    assert len(rig.seen(0x181)) == 1                      # no change, no event timer: silent
    rig.rpdo(0x06)                                        # -> READY TO SWITCH ON
    assert wait_for(lambda: len(rig.seen(0x181)) == 2)
    assert struct.unpack("<H", rig.seen(0x181)[-1])[0] & 0x6F == 0x21
    assert rig.seen(0x80) == []                           # no SYNC on the bus
    n.sdo[0x1800][5].raw = 20                             # event timer 20 ms
    time.sleep(0.3)
    assert 5 <= len(rig.seen(0x181)) - 2 <= 20


def test_a_drive_switched_off_is_silent_until_it_boots(rig):
    rig.drive.power_off()
    rig.node.sdo.RESPONSE_TIMEOUT = 0.2
    time.sleep(0.1)                     # a frame sent just before the power went off is delivered
    n0 = len(rig.frames)
    with pytest.raises(SdoCommunicationError):
        _ = rig.node.sdo[0x1000].raw
    assert not [i for _, i, _ in rig.frames[n0:] if i & 0x7F == 1]   # nothing from node 1
    rig.drive.boot()
    assert wait_for(lambda: b"\x00" in rig.seen(0x701))       # boot-up frame
    assert rig.node.sdo[0x1000].raw & 0xFFFF == 402


def test_a_lost_bus_faults_the_drive_and_it_reports_on_the_next_one(rig):
    """bus_lost: Fault 0x81FD (CAN bus off) at once, current 0; reattach to a bus: EMCY 0x81FD,
    PRE-OPERATIONAL, heartbeat and SDO as before (no boot-up frame: no power cycle)."""
    rig.configure_contract_pdos()
    rig.node.sdo[0x1017].raw = 20
    rig.enable()
    rig.rpdo(0x0F, 500)
    assert wait_for(lambda: rig.drive.applied_current == pytest.approx(1.5))
    rig.drive.bus_lost()
    assert rig.drive.state is State.FAULT and rig.drive.fault_code == 0x81FD
    assert rig.drive.applied_current == 0.0 and not rig.drive.attached
    n_boot = len([d for d in rig.seen(0x701) if d == b"\x00"])
    rig.drive.reattach(rig.net_s)
    assert wait_for(lambda: any(d[:2] == b"\xfd\x81" for d in rig.seen(0x81)))   # EMCY 0x81FD
    assert wait_for(lambda: rig.seen(0x701) and rig.seen(0x701)[-1] == b"\x7f")  # PRE-OPERATIONAL
    assert len([d for d in rig.seen(0x701) if d == b"\x00"]) == n_boot
    assert rig.node.sdo[0x603F].raw == 0x81FD


def test_a_synchronous_rpdo_delivered_late_latches_at_the_sync_it_was_on_the_bus_before(rig):
    """Frames reach a virtual channel in the order their senders got it, not of their stamps:
    an RPDO stamped before SYNC A but handled after SYNC B is latched at A (the player reports A),
    and a newer RPDO latched at B stays the drive's setpoint."""
    rig.configure_contract_pdos()
    rig.node.rpdo[1].trans_type = 1
    rig.node.rpdo[1].save()
    rig.node.sdo[0x6060].raw = 10
    rig.node.nmt.send_command(0x01)
    d, net = rig.drive, rig.net_s
    assert wait_for(lambda: d.nmt_state == "OPERATIONAL")

    def sync(t: float) -> None:
        net.notify(0x80, bytearray(), t)

    def rpdo(sp: int, t: float, cw: int = 0x0F) -> None:
        net.notify(0x201, bytearray(struct.pack("<Hh", cw, sp)), t)

    t0 = time.time()
    for k, cw in enumerate((0x06, 0x07, 0x0F)):          # each latched at the SYNC after it
        rpdo(0, t0 + 0.001 * k, cw)
        sync(t0 + 0.001 * k + 0.0005)
    assert d.state is State.OPERATION_ENABLED
    ta, tb, tc = t0 + 0.005, t0 + 0.010, t0 + 0.015
    sync(ta)
    sync(tb)
    d.clear_setpoint_log()
    rpdo(111, ta - 0.002)                                # on the bus before A, handled after B
    log = d.setpoint_log()
    assert [(r.raw, r.wall_ns) for r in log] == [(111, int(round(ta * 1e9)))]
    rpdo(222, tb - 0.001)                                # before B: latched at B
    sync(tc)
    rpdo(99, ta - 0.0023)                                # older than 111 at A: superseded there
    rpdo(112, ta - 0.001)                                # newer than 111 at A: A latched it...
    log = d.setpoint_log()
    assert [(r.raw, r.wall_ns) for r in log] == [(111, int(round(ta * 1e9))),
                                                 (222, int(round(tb * 1e9))),
                                                 (112, int(round(ta * 1e9)))]
    assert d._setpoint_raw == 222                        # ...and B's newer one is still in force
    rpdo(333, tc + 0.001)                                # after the last SYNC: waits for the next
    assert d._setpoint_raw == 222 and len(d.setpoint_log()) == 3


def test_txpdo_cob_ids_carry_bit_30_as_in_maxons_eds(rig):
    """TxPDO COB-IDs at power-on: 0x40000180 + id (bit 30: no RTR; TxPDO2-4 also bit 31, not
    valid). Written with bit 30 set they are accepted, and the PDO goes out on the low 11 bits;
    a 29-bit id is refused."""
    sdo = rig.node.sdo
    assert [sdo[0x1800 + n][1].raw for n in range(4)] == [
        0x40000181, 0xC0000281, 0xC0000381, 0xC0000481]
    assert sdo[0x1400][1].raw == 0x201                         # RxPDO1: no bit 30
    rig.configure_contract_pdos()
    sdo[0x1801][1].raw = 0xC0000281                           # not valid, then remap + enable
    sdo[0x1A01][0].raw = 0
    sdo[0x1A01][1].raw = 0x60410010
    sdo[0x1A01][0].raw = 1
    sdo[0x1801][2].raw = 1
    sdo[0x1801][1].raw = 0x40000281                           # valid, no RTR
    assert sdo[0x1801][1].raw == 0x40000281
    with pytest.raises(SdoAbortedError) as e:
        sdo[0x1802][1].raw = 0xA0000381                       # bit 29: a 29-bit CAN-ID
    assert e.value.code == 0x06090030
    rig.node.nmt.send_command(0x01)
    assert wait_for(lambda: rig.drive.nmt_state == "OPERATIONAL")
    rig.net_m.sync.transmit()
    assert wait_for(lambda: len(rig.seen(0x281)) == 1)
    assert struct.unpack("<H", rig.seen(0x281)[0])[0] & 0x4F == 0x40   # statusword
    assert not [i for _, i, _ in rig.frames if i & 0x40000000]


def test_the_rig_turns_the_supervision_off_and_says_so():
    from ff_hwbridge.sim.rig import RigConfig, SimRig, run_command

    rig = SimRig(RigConfig(bus={"interface": "virtual", "channel": f"test-sim-rig-{next(_chan)}"},
                           clock_period=0.0))
    try:
        d = rig.drive(1)
        assert d.interpolation_supervision and "supervision=on" in run_command(rig, "info 1")
        assert run_command(rig, "supervision 1 off") == "ok supervision"
        assert not d.interpolation_supervision and "supervision=off" in run_command(rig, "info 1")
        assert run_command(rig, "supervision 1 maybe").startswith("error")
    finally:
        rig.close()
    off = RigConfig(interpolation_supervision=False).drive_configs()[0]
    assert off.interpolation_supervision is False


def test_a_stop_ramp_brakes_in_the_drives_time_even_when_its_thread_is_held_off():
    """The quick-stop ramp's velocity loop is the drive's firmware: with the simulated drive's
    own thread held off for 1.5 s (a loaded machine), the arm still stops on the ramp and stays
    stopped (a braking current held by a starved thread would drive it back the other way, and
    a ramp cut short would free it at speed), then the drive ends Switch on disabled (0x605A =
    2, the shipped option) and the arm, at rest, has only friction. From 5 rad/s: above 3.8
    rad/s the model's friction (pv < 0, table 2) no longer brakes a free arm at all."""
    r, arm = _moving_rig({(0x605A, None): 2}, speed=5.0)
    step = r.drive._ramp_step
    try:
        q0, v0 = arm.state().q[0], arm.state().qd[0]
        r.drive._ramp_step = lambda: None                  # the drive's 2 ms thread starved
        r.rpdo(0x02, 0)
        assert wait_for(lambda: r.drive.braking)
        time.sleep(1.5)
        s = arm.state()
        alpha = 10000 * 2 * 3.141592653589793 / 60 / r.cfg.gear_ratio     # 0x6085, rad/s²
        assert abs(s.qd[0]) < 0.05, s                      # stopped, not reversed
        assert q0 < s.q[0] < q0 + v0 * v0 / alpha + 0.05, (q0, v0, s)
        r.drive._ramp_step = step
        assert wait_for(lambda: r.drive.state is State.SWITCH_ON_DISABLED, 5.0)
        assert wait_for(lambda: r.drive.applied_current == 0.0 and not r.drive.braking)
        time.sleep(0.3)
        assert abs(arm.state().qd[0]) < 0.01 and abs(arm.state().current[0]) == 0.0
    finally:
        r.drive._ramp_step = step
        r.close()
        arm.stop_clock()

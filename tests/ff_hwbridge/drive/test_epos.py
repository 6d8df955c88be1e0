"""EposMaster against a minimal canopen LocalNode drive on a python-can virtual bus, in-process.

The stand-in drive (``MiniEpos``) is test-only: SDO server (canopen), boot-up on NMT reset,
PDO maps reloaded from its object dictionary when written, RPDO controlword through the CiA 402
tables, TPDOs on SYNC, heartbeat, EMCY + Fault on request. Its "physics" is a trivial integrator
(the product's simulated drive uses the planner's model; this only checks the protocol).
"""
from __future__ import annotations

import logging
import struct
import threading
import time

import pytest

from ff_hwbridge.drive.config import ConfigError
from ff_hwbridge.drive.epos import EposError, EposMaster
from ff_hwbridge.protocol.cia402 import State
from tests.support.canopen_helpers import configure_and_enable, mini_config, unique_channel, waiter
from tests.support.mini_drive import MiniEpos


@pytest.fixture
def rig(request):
    family, n = getattr(request, "param", ("epos4", 1))
    channel = unique_channel("ff-test")
    cfg = mini_config(channel, family, n)
    drives = [MiniEpos(channel, j.node_id, j.units) for j in cfg.joints]
    master = EposMaster(cfg)
    master.connect()
    yield master, drives
    master.disconnect()
    for d in drives:
        d.close()


_wait = waiter(2.0)


@pytest.mark.parametrize("rig", [("epos4", 1), ("epos2", 2)], indirect=True)
def test_configure_sets_mode_heartbeat_and_pdo_maps(rig):
    master, drives = rig
    master.configure()
    for d in drives:
        d.maps()
        fam = d.family
        assert int(d.node.sdo[0x6060].raw) == (10 if fam == "epos4" else -3)
        assert int(d.node.sdo[0x1017].raw) == 10
        assert _wait(lambda d=d: d.node.nmt.state == "OPERATIONAL")
        sp = 0x6071 if fam == "epos4" else 0x2030
        assert d.rpdo_map == [(0x6040, 0), (sp, 0)]
        assert d.tpdo1_map == [(0x6041, 0), (0x6064, 0)]
        cur = (0x30D1, 2) if fam == "epos4" else (0x6078, 0)
        assert d.tpdo2_map == [(0x606C, 0), cur]
        assert int(d.node.sdo[0x1400][2].raw) == 1             # synchronous: latched at SYNC
        assert (int(d.node.sdo[0x60C2][1].raw), int(d.node.sdo[0x60C2][2].raw)) == (5, -3)  # 5 ms
        assert int(d.node.sdo[0x1800][2].raw) == 1 and int(d.node.sdo[0x1801][2].raw) == 1
        # TxPDO COB-IDs with bit 30 set (no RTR), as maxon's EDS has them
        assert d.rpdo_cob == 0x200 + d.id and d.tpdo_cobs == [0x40000180 + d.id, 0x40000280 + d.id]
        limit = int(d.node.sdo[0x3001][2].raw if fam == "epos4" else d.node.sdo[0x6410][2].raw)
        assert limit == 10000
    assert _wait(lambda: all(s is State.SWITCH_ON_DISABLED for s in master.states()))


def test_enable_sequence_goes_through_transitions_2_3_4(rig):
    master, drives = rig
    configure_and_enable(master)
    assert drives[0].transitions[-3:] == [2, 3, 4]
    sent = master.command_currents([1.5])
    assert sent.currents[0] == pytest.approx(1.5)
    assert _wait(lambda: drives[0].setpoint_raw == 500)       # 1.5 A / 3 A nominal = 500 ‰
    assert _wait(lambda: abs(master.feedback()[0].current - 1.5) < 1e-9)
    assert master.feedback()[0].velocity > 0
    master.disable()
    assert master.wait_for_state(State.SWITCHED_ON, 2.0)
    assert drives[0].transitions[-1] == 5
    assert drives[0].setpoint_raw == 0


def test_command_is_clamped_to_limit(rig):
    master, drives = rig
    configure_and_enable(master)
    sent = master.command_currents([1e9])
    assert sent.currents[0] == pytest.approx(10.0) and sent.reason
    assert _wait(lambda: drives[0].setpoint_raw == 3333)      # floor(10 A / 3 A * 1000)
    master.command_currents([float("nan")])
    assert _wait(lambda: drives[0].setpoint_raw == 0)
    assert max(abs(sp) for _, sp in drives[0].rx_log) <= 3333


def test_emcy_latches_safe_state_and_fault_reset_recovers(rig):
    master, drives = rig
    configure_and_enable(master)
    master.command_currents([2.0])
    drives[0].raise_fault(0x2310)
    assert _wait(lambda: master.latched, 1.0)
    assert "EMCY" in master.fault_reason and "0x2310" in master.fault_reason
    time.sleep(0.02)               # RPDOs sent before the latch take effect at the next SYNC
    assert drives[0].setpoint_raw == 0
    n = len(drives[0].rx_log)
    master.command_currents([5.0])                           # refused while latched
    assert _wait(lambda: len(drives[0].rx_log) > n)
    assert all(sp == 0 for _, sp in drives[0].rx_log[n:])
    with pytest.raises(EposError):
        master.enable()
    master.fault_reset()
    assert not master.latched
    assert master.wait_for_state(State.OPERATION_ENABLED, 2.0)
    assert 15 in drives[0].transitions


def test_heartbeat_loss_latches_safe_state(rig):
    master, drives = rig
    configure_and_enable(master)
    master.command_currents([1.0])
    drives[0].stop_heartbeat()
    assert _wait(lambda: master.latched, 2.0)
    assert "heartbeat lost" in master.fault_reason
    assert _wait(lambda: drives[0].state is State.QUICK_STOP_ACTIVE)
    assert drives[0].transitions[-1] == 11
    assert drives[0].setpoint_raw == 0


def test_the_object_dictionary_can_come_from_the_drives_eds(tmp_path):
    import re
    from pathlib import Path

    import ff_hwbridge.sim as sim

    eds = Path(sim.__file__).parent / "epos4.eds"
    channel = unique_channel("ff-test")
    cfg = mini_config(channel, "epos4", 1, joint={"eds": str(eds)})
    drive = MiniEpos(channel, 1, cfg.joints[0].units)
    master = EposMaster(cfg)
    try:
        master.connect()
        configure_and_enable(master)
        master.command_currents([1.5])
        assert _wait(lambda: drive.setpoint_raw == 500)       # 1.5 A of 3 A nominal, per mille
    finally:
        master.disconnect()
        drive.close()
    # an EDS without the target torque: refused on connect, naming what is missing
    text = re.sub(r"\[6071\][^\[]*", "", eds.read_text(errors="replace"))
    text = text.replace("0x6071", "0x6072")                  # and out of the object lists
    bad = tmp_path / "no6071.eds"
    bad.write_text(text)
    m2 = EposMaster(mini_config(unique_channel("ff-test"), "epos4", 1, joint={"eds": str(bad)}))
    with pytest.raises(EposError, match="lacks object.*0x6071"):
        m2.connect()
    with pytest.raises(Exception, match="no such file"):
        mini_config(channel, "epos4", 1, joint={"eds": str(tmp_path / "missing.eds")})


def test_feedback_is_stamped_with_the_sync_it_answers(rig):
    master, drives = rig
    configure_and_enable(master)
    assert master.echo                        # the virtual bus shows the master its own SYNC
    for _ in range(5):
        time.sleep(0.02)
        fb = master.feedback()[0]
        syncs = {ev.bus_ns for ev in master.sync_watch.since(0)}
        assert fb.sample_ns in syncs, (fb.sample_ns, sorted(syncs)[-3:])


def test_a_tpdo_received_before_its_sync_gets_that_sync_as_its_sample_instant(rig):
    master, drives = rig
    configure_and_enable(master)
    drives[0].answer_sync = False             # only the frames below reach the callbacks
    master.stop_sync()
    time.sleep(0.02)
    d = master._drives[0]
    period = master.sync_watch.period_ns
    sync_ns = master.sync_watch.latest().bus_ns + period
    tpdo_ns = sync_ns + period // 10
    tpdo = struct.pack(d.tx1_fmt, 0x0237, 1000)               # Operation enabled
    master.network.notify(0x181, bytearray(tpdo), tpdo_ns * 1e-9)
    assert abs(master.feedback()[0].sample_ns - tpdo_ns) < 1000    # no SYNC seen for it yet
    master.network.notify(0x80, bytearray(), sync_ns * 1e-9)
    assert abs(master.feedback()[0].sample_ns - sync_ns) < 1000    # ns: float seconds rounding
    master.network.notify(0x80, bytearray(), (sync_ns + period) * 1e-9)
    assert abs(master.feedback()[0].sample_ns - sync_ns) < 1000    # a later SYNC does not move it


def test_a_failed_bus_is_said_at_once_and_stops_the_drive(rig):
    import can

    master, drives = rig
    configure_and_enable(master)
    master.command_currents([1.0])
    assert _wait(lambda: drives[0].setpoint_raw != 0)
    t0 = time.monotonic()

    def dead(*_a, **_k):
        raise can.CanOperationError("adapter gone")

    master.network.bus.recv = dead          # python-can's notifier stops and keeps the exception
    assert _wait(lambda: master.latched, 2.0)
    assert master.fault_reason.startswith("CAN bus lost: CanOperationError: adapter gone"), master.fault_reason
    assert time.monotonic() - t0 < master.config.heartbeat_timeout + 0.5


def test_a_failing_send_logs_one_traceback_then_counts(rig, caplog):
    import can

    master, drives = rig
    configure_and_enable(master)
    bus = master.network.bus
    send = bus.send

    def full(*_a, **_k):
        raise can.CanOperationError("transmit buffer full")

    with caplog.at_level(logging.WARNING, logger="ff_hwbridge.drive.epos"):
        bus.send = full
        errors = master.tx_errors
        for _ in range(20):
            master.command_currents([0.5])
        bus.send = send
        master.command_currents([0.5])
    assert master.tx_errors - errors >= 20
    failed = [r for r in caplog.records if r.getMessage().startswith("RPDO to node 1 failed")]
    assert len(failed) == 1 and failed[0].exc_info is not None
    assert any(r.getMessage().startswith("RPDO to node 1 goes through again after ")
               for r in caplog.records)
    assert _wait(lambda: drives[0].setpoint_raw != 0)


def test_setpoint_watchdog_and_feedback_loss(rig):
    master, drives = rig
    configure_and_enable(master)
    master.note_setpoint(motion_running=True)
    master.command_currents([1.0])
    assert _wait(lambda: master.latched, 2.0)
    assert "setpoint watchdog" in master.fault_reason
    master.fault_reset()
    assert master.wait_for_state(State.OPERATION_ENABLED, 5.0), (master.fault_reason, list(master.events)[-5:])
    drives[0].answer_sync = False                            # drive stops sending TPDOs
    assert _wait(lambda: master.latched, 2.0)
    assert "feedback lost" in master.fault_reason


def test_missing_node_gives_clear_error():
    channel = unique_channel("ff-test")
    master = EposMaster(mini_config(channel, boot_timeout=0.2, boot_wait=0.5))
    master.connect()
    try:
        t0 = time.monotonic()
        with pytest.raises(EposError, match=r"no boot-up frame within 0.5 s \([23] NMT reset"):
            master.configure()
        assert time.monotonic() - t0 >= 0.5                   # it did wait, with retries
    finally:
        master.disconnect()


def test_a_drive_powered_late_is_waited_for(caplog):
    channel = unique_channel("ff-test")
    cfg = mini_config(channel, boot_timeout=0.2, boot_wait=5.0)
    master = EposMaster(cfg)
    master.connect()
    drives = []

    def power_on_late() -> None:
        time.sleep(0.45)                                      # after two unanswered resets
        drives.append(MiniEpos(channel, 1, cfg.joints[0].units))

    t = threading.Thread(target=power_on_late)
    t.start()
    try:
        with caplog.at_level("WARNING", logger="ff_hwbridge.drive.epos"):
            master.configure()                                # blocks until the drive is there
        t.join()
        assert "waiting for the drive" in caplog.text
        assert _wait(lambda: drives[0].node.nmt.state == "OPERATIONAL")
    finally:
        master.disconnect()
        t.join()
        for d in drives:
            d.close()


def test_identity_is_checked(rig):
    master, drives = rig
    drives[0].node.data_store.setdefault(0x1018, {})[1] = (0x1234).to_bytes(4, "little")
    with pytest.raises(EposError, match=r"vendor id 0x1018:01 = 0x00001234, not maxon"):
        master.configure()


def test_configure_writes_the_drive_reactions_and_the_master_heartbeat(rig):
    master, drives = rig
    master.configure()
    sdo = drives[0].node.sdo
    c = master.config
    assert c.master_heartbeat_ms == 100 and c.master_heartbeat_timeout_ms == 300   # defaults: on
    # (300 = max(3 x 100 ms, heartbeat_timeout 0.3 s))
    assert int(sdo[0x1016][1].raw) == (127 << 16) | 300
    assert (int(sdo[0x605A].raw), int(sdo[0x605E].raw), int(sdo[0x6007].raw),
            int(sdo[0x1029][1].raw)) == (2, 2, 1, 0)
    assert c.rpdo_timeout_ms == 600                            # max(500 ms, 2 x heartbeat_timeout)
    assert int(sdo[0x1400][5].raw) == 600                     # RPDO deadline, ms
    assert (int(sdo[0x60C2][1].raw), int(sdo[0x60C2][2].raw)) == (5, -3)   # 5 ms SYNC
    assert "joint1.drive_notes" not in master.status()       # every object was there


def test_node_leaving_operational_or_rebooting_latches(rig):
    master, drives = rig
    configure_and_enable(master)
    assert _wait(lambda: master.status()["joint1.nmt"] == "OPERATIONAL")
    drives[0].node.nmt.send_command(0x02)                    # the drive goes to NMT STOPPED
    assert _wait(lambda: master.latched, 2.0)
    assert "left OPERATIONAL" in master.fault_reason
    # fault reset sets the node up again (NMT reset communication, SDO, PDO, start)
    master.fault_reset()
    assert master.wait_for_state(State.OPERATION_ENABLED, 3.0), master.events
    assert drives[0].node.nmt.state == "OPERATIONAL"
    drives[0].node.nmt.send_command(0x82)                    # spontaneous reboot: boot-up frame
    drives[0].node.nmt.send_command(0x80)
    assert _wait(lambda: master.latched, 2.0)
    assert "rebooted" in master.fault_reason


def test_lost_quick_stop_is_repeated_and_lost_setpoint_heals(rig):
    master, drives = rig
    configure_and_enable(master)
    master.command_currents([1.5])
    assert _wait(lambda: drives[0].setpoint_raw == 500)
    drives[0].drop_rx = True                                 # every RPDO to the drive is lost
    master.quick_stop("test: quick stop")
    time.sleep(0.05)
    assert drives[0].state is State.OPERATION_ENABLED and drives[0].setpoint_raw == 500
    drives[0].drop_rx = False                                # frames flow again
    assert _wait(lambda: drives[0].state is State.QUICK_STOP_ACTIVE and drives[0].setpoint_raw == 0)
    master.fault_reset()
    assert master.wait_for_state(State.OPERATION_ENABLED, 2.0)
    drives[0].drop_rx = True
    master.command_currents([0.6])                           # this setpoint is lost ...
    time.sleep(0.02)
    drives[0].drop_rx = False
    assert _wait(lambda: drives[0].setpoint_raw == 200)      # ... and healed by the refresh


def test_master_heartbeat_is_produced_and_consumed_by_the_drive():
    channel = unique_channel("ff-test")
    cfg = mini_config(channel, master_heartbeat_ms=20)
    drive = MiniEpos(channel, 1, cfg.joints[0].units)
    seen = []
    drive.net.subscribe(0x77F, lambda cid, data, ts: seen.append(bytes(data)))
    master = EposMaster(cfg)
    master.connect()
    try:
        master.configure()
        # consumer time max(3 x 20 ms, heartbeat_timeout 0.3 s)
        assert int(drive.node.sdo[0x1016][1].raw) == (127 << 16) | 300
        assert _wait(lambda: len(seen) >= 3)
        assert set(seen) == {b"\x05"}
        master.disconnect()
        n = len(seen)
        time.sleep(0.1)
        assert len(seen) <= n + 1                              # stops with the master
    finally:
        master.disconnect()
        drive.close()


@pytest.mark.parametrize("joint, words", [({"position_limits": [-0.1, 0.1]}, "position envelope"),
                                          ({"velocity_limit": 0.2}, "velocity envelope")])
def test_envelope_latches_the_safe_state_and_rearms_inside(joint, words):
    channel = unique_channel("ff-test")
    cfg = mini_config(channel, joint=joint)
    drive = MiniEpos(channel, 1, cfg.joints[0].units)
    master = EposMaster(cfg)
    master.connect()
    try:
        configure_and_enable(master)
        master.command_currents([0.6])                       # the stand-in moves: 0.39 rad/s
        assert _wait(lambda: master.latched, 2.0)
        assert words in master.fault_reason and "joint1" in master.fault_reason
        assert _wait(lambda: drive.setpoint_raw == 0)         # zero current at the drive
        master.fault_reset()                                  # still outside: not re-latched ...
        assert master.wait_for_state(State.OPERATION_ENABLED, 2.0)
        time.sleep(0.05)
        assert not master.latched
    finally:
        master.disconnect()
        drive.close()


def test_feedback_every_sets_the_tpdos_transmission_type():
    """``feedback_every`` N: the status and motion TPDOs answer every N-th SYNC (CiA 301 type N),
    and the feedback watchdog's default grows with it."""
    channel = unique_channel("ff-test")
    cfg = mini_config(channel, "epos4", 1, feedback_every=4)
    assert cfg.feedback_timeout == pytest.approx(0.3)           # the heartbeat's patience
    slow = mini_config(channel, "epos4", 1, feedback_every=40)
    assert slow.feedback_timeout == pytest.approx(3 * 0.005 * 40 + 0.1)   # 3 TPDO periods + margin
    drives = [MiniEpos(channel, j.node_id, j.units) for j in cfg.joints]
    master = EposMaster(cfg)
    try:
        master.connect()
        master.configure()
        d = drives[0]
        assert int(d.node.sdo[0x1800][2].raw) == 4 and int(d.node.sdo[0x1801][2].raw) == 4
        assert int(d.node.sdo[0x1400][2].raw) == 1       # the setpoint stays synchronous
    finally:
        master.disconnect()
        for d in drives:
            d.close()
    for bad in (0, 241, 2.5, True):
        with pytest.raises(ConfigError, match="feedback_every must be an integer 1..240"):
            mini_config(channel, "epos4", 1, feedback_every=bad)

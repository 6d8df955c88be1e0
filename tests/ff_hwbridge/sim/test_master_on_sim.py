"""EposMaster against the simulated EPOS (in-process, python-can virtual bus): motor data checked
against the drive, EMCY warnings vs errors, the error history, the drive stopping by itself when
the master dies, the envelope and the e-stop."""
from __future__ import annotations

import time

import pytest

from ff_hwbridge.drive.epos import EposError, EposMaster
from ff_hwbridge.protocol.cia402 import State
from ff_hwbridge.sim.drive import DriveConfig, SimEpos
from tests.support.canopen_helpers import configure_and_enable, mini_config, open_network, unique_channel, waiter

wait_for = waiter(3.0)


class SimBench:
    """One SimEpos (NullPlant) and one EposMaster on a private virtual channel."""

    def __init__(self, drive: DriveConfig | None = None, **config) -> None:
        self.channel = unique_channel("ff-sim-master")
        self.net = open_network(self.channel)
        self.drive = SimEpos(drive or DriveConfig())
        self.drive.attach(self.net)
        self.drive.boot()
        config.setdefault("heartbeat_timeout", 0.3)
        self.master = EposMaster(mini_config(self.channel, **config))
        self.master.connect()

    def close(self) -> None:
        self.master.disconnect()
        self.drive.close()
        self.net.disconnect()


@pytest.fixture
def bench():
    b = SimBench()
    yield b
    b.close()


def test_nominal_current_disagreement_is_refused_with_both_values():
    b = SimBench(DriveConfig(nominal_current=2.5))           # the YAML says 3 A
    try:
        with pytest.raises(EposError) as exc:
            b.master.configure()
        text = str(exc.value)
        assert "nominal current 0x3001:01: drive 2.5 A, config units.nominal_current 3 A" in text
        assert "-16.7 %" in text and "scaling_source" in text
    finally:
        b.close()


def test_scaling_source_drive_takes_the_drive_value_and_config_writes_its_own():
    b = SimBench(DriveConfig(nominal_current=2.5), scaling_source="drive")
    try:
        configure_and_enable(b.master)
        assert b.master.units[0].nominal_current == pytest.approx(2.5)
        b.master.command_currents([1.0])                      # 1 A = 400 ‰ of 2.5 A
        assert wait_for(lambda: b.drive.applied_current == pytest.approx(1.0, abs=0.003))
    finally:
        b.close()
    b = SimBench(DriveConfig(nominal_current=2.5), scaling_source="config")
    try:
        configure_and_enable(b.master)
        assert b.drive.node.sdo[0x3001][1].raw == 3000        # the config's, written
        b.master.command_currents([1.0])
        assert wait_for(lambda: b.drive.applied_current == pytest.approx(1.0, abs=0.003))
    finally:
        b.close()


def test_a_warning_is_reported_and_does_not_latch(bench):
    m = bench.master
    configure_and_enable(m)
    m.command_currents([1.0])
    bench.drive.raise_warning(0xFF01)
    assert wait_for(lambda: m.status()["joint1.last_warning"] != "")
    assert wait_for(lambda: m.status()["joint1.warning"] is True)          # statusword bit 7
    assert "0xFF01" in m.status()["joint1.last_warning"]
    time.sleep(0.05)
    assert not m.latched
    assert bench.drive.applied_current == pytest.approx(1.0, abs=0.003)


def test_an_error_latches_and_the_error_history_is_read(bench):
    m = bench.master
    configure_and_enable(m)
    m.command_currents([1.0])
    bench.drive.raise_emcy(0x2310)
    assert wait_for(lambda: m.latched)
    assert "0x2310 over current (error)" in m.fault_reason
    assert wait_for(lambda: m.status()["joint1.error_history"] != "")
    hist = m.status()["joint1.error_history"]
    assert "0x603F: 0x2310 over current" in hist and "0x1003: 0x2310" in hist


def test_a_dead_master_stops_the_drive_within_half_a_second(bench):
    """Everything of the master goes silent at once (as on SIGKILL): the drive consumes the
    master's heartbeat (default on, 300 ms) and faults with 0x8130 by itself."""
    m = bench.master
    configure_and_enable(m)
    m.command_currents([1.5])
    assert wait_for(lambda: bench.drive.applied_current == pytest.approx(1.5, abs=0.003))
    # CiA 301: the consumer is armed by the first heartbeat it sees
    assert wait_for(lambda: 127 in bench.drive.heartbeats_seen())
    m._stop_monitor()
    m.stop_sync()
    m.stop_master_heartbeat()
    t_dead = time.monotonic()
    m.network.disconnect()                                    # no frame leaves the master any more
    m.network = None
    assert wait_for(lambda: bench.drive.applied_current == 0.0, 1.0)
    dt = time.monotonic() - t_dead
    assert 0.25 < dt < 0.5, dt                                # the consumer time, then at once
    assert bench.drive.state is State.FAULT and bench.drive.fault_code == 0x8130


def test_a_hung_master_whose_sync_and_heartbeat_go_on_is_stopped_by_the_drive():
    """The master's threads stop (its bus receiver and monitor: no RPDO any more) while its SYNC
    and heartbeat go on from python-can's periodic senders, as the kernel's broadcast manager
    keeps them going on SocketCAN for a frozen process: the drive's interpolation supervision
    (0x60C2 = the 5 ms SYNC period, CST) faults it with 0x8250 within a few periods."""
    bench = SimBench()
    try:
        m = bench.master
        configure_and_enable(m)
        m.command_currents([1.5])
        assert wait_for(lambda: bench.drive.applied_current == pytest.approx(1.5, abs=0.003))
        assert wait_for(lambda: 127 in bench.drive.heartbeats_seen())   # consumer armed
        assert bench.drive.state is State.OPERATION_ENABLED, bench.drive.fault_code
        m._stop_monitor()
        t_hung = time.monotonic()
        m.network.notifier.stop()                             # no SYNC seen: no RPDO sent
        assert wait_for(lambda: bench.drive.state is not State.OPERATION_ENABLED, 1.0)
        dt = time.monotonic() - t_hung
        assert dt < 0.5, dt
        assert bench.drive.fault_code == 0x8250 and bench.drive.applied_current == 0.0
        assert time.monotonic() - bench.drive.heartbeats_seen()[127] < 0.3   # heartbeat alive
        assert bench.drive.last_sync_ns > time.time_ns() - 100_000_000        # SYNC alive
    finally:
        bench.close()


def test_envelope_and_estop(bench):
    b = SimBench()
    try:
        m = b.master
        configure_and_enable(m)
        reason = m.estop("operator button")
        assert reason == "e-stop: operator button" and m.latched
        assert wait_for(lambda: b.drive.state is not State.OPERATION_ENABLED)
        assert b.drive.applied_current == 0.0
    finally:
        b.close()

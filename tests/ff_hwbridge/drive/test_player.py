"""SetpointPlayer with ``setpoint_timing: on_receipt`` (stamped setpoint -> safety guard -> units
-> RPDO at its stamp) against the in-process stand-in drive (``MiniEpos``) on python-can's
virtual bus; no rclpy. The synchronous player: ``test_sync_player.py``."""
from __future__ import annotations

import time

import pytest

from ff_hwbridge.drive.epos import EposMaster
from ff_hwbridge.drive.player import PlayerConfig, SetpointPlayer, SetpointRejected
from tests.support.canopen_helpers import configure_and_enable, mini_config, unique_channel, waiter
from tests.support.mini_drive import MiniEpos

# s: how late a setpoint may reach the drive after its stamp. The player itself sends within
# ~0.1 ms; the margin is for a loaded 2-core machine holding this process off the CPU.
LATE_TOLERANCE = 0.05

_wait = waiter(2.0)


@pytest.fixture
def player():
    channel = unique_channel("ff-player")
    # setpoint watchdog 1 s: the tests feed single setpoints, not a stream
    cfg = mini_config(channel, setpoint_timeout=1.0, setpoint_timing="on_receipt")
    drive = MiniEpos(channel, 1, cfg.joints[0].units)
    master = EposMaster(cfg)
    master.connect()
    p = SetpointPlayer(master)
    try:
        configure_and_enable(master)
        p.start()
        yield p, drive
    finally:
        p.close()
        master.disconnect()
        drive.close()


def _arrival_of(drive: MiniEpos, raw: int) -> int:
    """time.time_ns() at which the drive first received setpoint ``raw``."""
    return next(t for (_, sp), t in zip(list(drive.rx_log), list(drive.rx_wall_ns)) if sp == raw)


def test_config_follows_the_bridge_config():
    cfg = mini_config("unused", spin_margin=0.001, scheduler_rt_priority=0)
    assert mini_config("unused").rt_priority == 50                        # auto, synchronous
    assert mini_config("unused", setpoint_timing="on_receipt").rt_priority == 0
    assert PlayerConfig.from_bridge(cfg) == PlayerConfig(spin_margin=0.001, rt_priority=0)


def test_stamped_setpoint_is_applied_at_its_stamp(player):
    p, drive = player
    stamp = time.time_ns() + 100_000_000
    p.submit(stamp, [1.5], seq=7, profile_id="p")
    assert _wait(lambda: drive.setpoint_raw == 500)             # 1.5 A / 3 A nominal = 500 ‰
    arrived = _arrival_of(drive, 500)
    assert stamp <= arrived <= stamp + LATE_TOLERANCE * 1e9     # not before its stamp
    (report,) = p.take_applied()
    assert report.stamp_ns == stamp and stamp <= report.sent_ns <= arrived
    assert report.currents == pytest.approx((1.5,))
    assert (report.seq, report.profile_id, report.last, report.reason) == (7, "p", False, None)
    st = p.stats()
    assert st.count == 1 and 0.0 <= st.min_us <= LATE_TOLERANCE * 1e6
    assert p.diagnostics()["switch_count"] == 1 and p.diagnostics()["pending_setpoints"] == 0
    ((rec_stamp, rec_sent),) = p.records()
    assert rec_stamp == stamp and rec_sent >= report.sent_ns


def test_over_limit_current_is_clamped(player):
    p, drive = player
    p.submit(time.time_ns() + 10_000_000, [30.0], seq=1, profile_id="p")
    assert _wait(lambda: drive.setpoint_raw == 3333)            # floor(10 A / 3 A * 1000)
    assert _wait(lambda: p.stats().count == 1)
    (report,) = p.take_applied()
    assert report.currents[0] == pytest.approx(9.999, abs=1e-3) and report.reason
    assert max(abs(sp) for _, sp in drive.rx_log) <= 3333


def test_nan_becomes_zero_current(player):
    p, drive = player
    t0 = time.time_ns() + 10_000_000
    p.submit(t0, [1.5], seq=1)
    p.submit(t0 + 20_000_000, [float("nan")], seq=2)
    assert _wait(lambda: p.stats().count == 2)
    assert _wait(lambda: drive.setpoint_raw == 0)
    first, second = p.take_applied()
    assert first.currents == pytest.approx((1.5,)) and first.reason is None
    assert second.currents == (0.0,) and second.reason


def test_stop_commands_zero_current_and_drops_pending(player):
    p, drive = player
    p.submit(time.time_ns(), [1.5], seq=1)
    assert _wait(lambda: drive.setpoint_raw == 500)
    p.submit(time.time_ns() + 100_000_000, [3.0], seq=2)
    p.stop()
    assert p.pending == 0
    assert _wait(lambda: drive.setpoint_raw == 0)
    time.sleep(0.15)                                             # past the dropped one's stamp
    assert all(sp != 1000 for _, sp in drive.rx_log)            # the dropped 3 A never went out
    assert [a.seq for a in p.take_applied()] == [1]


def test_safe_state_rejects_setpoints_and_drops_pending(player):
    p, drive = player
    with pytest.raises(SetpointRejected, match="current"):
        p.submit(time.time_ns(), [1.0, 2.0])                     # two currents for one joint
    p.submit(time.time_ns() + 500_000_000, [1.0], seq=1, profile_id="p")
    assert p.pending == 1
    p.master.quick_stop("test: quick stop")
    assert p.pending == 0
    with pytest.raises(SetpointRejected, match="safe state"):
        p.submit(time.time_ns(), [1.0])
    assert _wait(lambda: drive.setpoint_raw == 0)

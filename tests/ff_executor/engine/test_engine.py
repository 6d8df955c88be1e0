"""Unit tests of the executor's streaming engine (no ROS, fake clock)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from ff_executor.engine.engine import (
    NS,
    EngineConfig,
    ProfileRejected,
    Setpoint,
    SettleDetector,
    Stream,
    StreamRunner,
    build_setpoints,
    check_profile,
    check_start_state,
    estimate_applied_times,
    resolve_start,
    timing_stats,
)
from ff_planner.model.profile import CurrentProfile

CUR = [-3.70, 2.27, 0.58, 6.94, -4.76]


def motion(currents=CUR, names=("joint1",), cfg=None, pid="p1", q0=(0.0,), qf=(1.0,)):
    cfg = cfg or EngineConfig()
    prof = CurrentProfile.uniform(currents, 1.0)
    return check_profile(prof, names, q0, qf, cfg, pid)


class FakeClock:
    def __init__(self, t0=10 * NS):
        self.t = t0

    def __call__(self) -> int:
        return self.t

    def sleep(self, s: float) -> None:
        self.t += max(int(s * NS), 100_000)


# --- configuration ----------------------------------------------------------------------------
def test_config_refuses_bad_values():
    with pytest.raises(ValueError, match="start_margin"):
        EngineConfig(lead_time=0.5, start_margin=0.1)
    with pytest.raises(ValueError, match="current limits"):
        EngineConfig(joint_names=("a", "b"), current_limits=(1.0, 2.0, 3.0))
    with pytest.raises(ValueError, match="repeat"):
        EngineConfig(joint_names=("a", "a"), current_limits=(1.0,))
    with pytest.raises(ValueError, match="lead_time"):
        EngineConfig(lead_time=float("nan"))
    assert EngineConfig(joint_names=("a", "b"), current_limits=(3.0,)).current_limits == (3.0, 3.0)


# --- profile checks ---------------------------------------------------------------------------
def test_check_profile_accepts_a_good_profile():
    m = motion()
    assert m.profile.n_steps == 5 and m.profile_id == "p1"
    assert m.q0.tolist() == [0.0] and m.qf.tolist() == [1.0]


@pytest.mark.parametrize("kwargs, text", [
    (dict(currents=[1.0, 11.0, -1.0]), "beyond its limit"),
    (dict(names=("elbow",)), "do not match"),
    (dict(q0=(0.0, 1.0)), "q0 has 2"),
    (dict(qf=(float("nan"),)), "finite"),
])
def test_check_profile_refuses(kwargs, text):
    with pytest.raises(ProfileRejected, match=text):
        motion(**kwargs)


def test_check_profile_refuses_bad_times():
    cfg = EngineConfig()
    bad = CurrentProfile(np.array([0.0, 0.5, 0.4, 0.95]), np.ones((3, 1)), 1.0)
    with pytest.raises(ProfileRejected, match="increase"):
        check_profile(bad, ["joint1"], [0], [1], cfg)
    nan = CurrentProfile(np.array([0.0, float("nan"), 0.95]), np.ones((2, 1)), 1.0)
    with pytest.raises(ProfileRejected, match="finite"):
        check_profile(nan, ["joint1"], [0], [1], cfg)
    late = CurrentProfile(np.array([0.0, 0.5, 0.99]), np.ones((2, 1)), 1.0, 0.05)
    with pytest.raises(ProfileRejected, match="tf - coast"):
        check_profile(late, ["joint1"], [0], [1], cfg)
    short = CurrentProfile(np.array([0.0, 0.00001, 0.95]), np.ones((2, 1)), 1.0)
    with pytest.raises(ProfileRejected, match="min_step"):
        check_profile(short, ["joint1"], [0], [1], cfg)
    with pytest.raises(ProfileRejected, match="max_steps"):
        check_profile(CurrentProfile.uniform(np.ones(20), 1.0), ["joint1"], [0], [1],
                      EngineConfig(max_steps=10))
    with pytest.raises(ProfileRejected, match="max_move_time"):
        check_profile(CurrentProfile.uniform([1.0], 700.0), ["joint1"], [0], [1], cfg)


def test_check_profile_reorders_joints_to_the_bridge_order():
    cfg = EngineConfig(joint_names=("joint1", "joint2"), current_limits=(10.0, 5.0))
    prof = CurrentProfile.uniform([[1.0, 2.0], [3.0, 4.0]], 1.0)
    m = check_profile(prof, ["joint2", "joint1"], [0.5, -0.5], [0.0, 1.0], cfg)
    assert m.profile.currents.tolist() == [[2.0, 1.0], [4.0, 3.0]]
    assert m.q0.tolist() == [-0.5, 0.5] and m.qf.tolist() == [1.0, 0.0]
    # the limit applies to the joint it belongs to after reordering
    with pytest.raises(ProfileRejected, match="joint2"):
        check_profile(CurrentProfile.uniform([[6.0, 1.0]], 1.0), ["joint2", "joint1"], [0, 0],
                      [0, 0], cfg)


def test_check_start_state():
    m = motion()
    cfg = EngineConfig()
    check_start_state([0.01], [0.0], m, cfg)
    with pytest.raises(ProfileRejected, match="move the arm to q0"):
        check_start_state([0.5], [0.0], m, cfg)
    with pytest.raises(ProfileRejected, match="moving"):
        check_start_state([0.0], [0.3], m, cfg)
    with pytest.raises(ProfileRejected, match="no joint state"):
        check_start_state(None, None, m, cfg)
    check_start_state([5.0], [0.0], m, EngineConfig(start_tolerance=math.inf))


def test_resolve_start():
    cfg = EngineConfig(lead_time=0.1, start_margin=0.25)
    now = 100 * NS
    assert resolve_start(0, now, cfg) == now + int(0.25 * NS)
    assert resolve_start(now + 2 * NS, now, cfg) == now + 2 * NS
    assert resolve_start(now + NS // 100, now, cfg) == now + int(0.25 * NS)   # too soon: moved
    with pytest.raises(ProfileRejected, match="max_start_wait"):
        resolve_start(now + 100 * NS, now, cfg)


# --- setpoints --------------------------------------------------------------------------------
def test_build_setpoints_one_per_switch_and_final_zero():
    m = motion()
    start = 5 * NS
    sps = build_setpoints(m, start)
    assert len(sps) == 6
    assert [s.seq for s in sps] == list(range(6))
    assert [s.currents[0] for s in sps[:5]] == CUR
    dt = 0.95 / 5
    for i, s in enumerate(sps[:5]):
        assert s.stamp_ns == start + round(i * dt * NS)
        assert not s.last and s.switch and s.profile_id == "p1"
    final = sps[-1]
    assert final.last and final.currents == (0.0,)
    assert final.stamp_ns == start + round(0.95 * NS)    # tf - coast


def test_build_setpoints_merges_equal_steps_and_adds_keepalives():
    m = motion(currents=[2.0, 2.0, -1.0])
    sps = build_setpoints(m, 0)
    assert [s.currents[0] for s in sps] == [2.0, -1.0, 0.0]
    ka = build_setpoints(m, 0, keepalive=0.05)
    stamps = [s.stamp_ns for s in ka]
    assert stamps == sorted(stamps) and ka[-1].last
    assert max(np.diff(stamps)) <= 0.05 * NS * 1.25 + 1
    assert [s.currents[0] for s in ka if s.switch] == [2.0, -1.0, 0.0]
    assert len(ka) > 15 and [s.seq for s in ka] == list(range(len(ka)))


# --- streaming --------------------------------------------------------------------------------
def test_stream_publishes_each_setpoint_lead_time_ahead():
    m = motion()
    clock = FakeClock()
    start = clock.t + int(0.25 * NS)
    stream = Stream(build_setpoints(m, start), lead_time=0.1)
    sent = []
    runner = StreamRunner(stream, lambda sp: sent.append((clock.t, sp)), clock, clock.sleep)
    assert runner.run() is False
    assert [sp.seq for _, sp in sent] == list(range(6))
    for t_pub, sp in sent:
        ahead = (sp.stamp_ns - t_pub) / NS
        assert 0.09 <= ahead <= 0.1 + 1e-9, ahead          # never late, never much earlier
    assert not stream.late()
    assert clock.t >= stream.end_ns


def test_stream_commanded_follows_the_plan():
    m = motion()
    stream = Stream(build_setpoints(m, 0), lead_time=0.1)
    stream.due(2 * NS)
    assert stream.commanded(-1) == (0.0,)
    assert stream.commanded(0) == (CUR[0],)
    assert stream.commanded(int(0.2 * NS)) == (CUR[1],)
    assert stream.commanded(int(0.96 * NS)) == (0.0,)


def test_cancel_sends_zero_now_and_after_every_pending_stamp():
    m = motion()
    clock = FakeClock()
    stream = Stream(build_setpoints(m, clock.t + int(0.25 * NS)), lead_time=0.3)
    sent: list[Setpoint] = []
    cancel_at = stream.start_ns + int(0.3 * NS)
    runner = StreamRunner(stream, sent.append, clock, clock.sleep,
                          should_cancel=lambda: clock.t >= cancel_at)
    assert runner.run() is True
    first = next(i for i, s in enumerate(sent) if s.last)
    zeros = sent[first:]
    assert all(s.currents == (0.0,) and s.last for s in zeros)   # nothing after but zeros
    assert abs(zeros[0].stamp_ns - clock.t) < NS // 1000          # stamped now
    # every non-zero setpoint already handed over with a later stamp is overridden 1 us after it
    pending = [s for s in sent[:first] if s.stamp_ns >= zeros[0].stamp_ns and any(s.currents)]
    assert pending, "the lead time should leave setpoints pending at the bridge"
    for s in pending:
        assert any(z.stamp_ns - s.stamp_ns == 1000 for z in zeros)
    # simulate a bridge that applies everything in stamp order: current is zero after cancel
    # except for 1 us after each overridden stamp
    timeline = sorted(sent, key=lambda s: (s.stamp_ns, s.seq))
    on = [(a.stamp_ns, b.stamp_ns) for a, b in zip(timeline, timeline[1:])
          if any(a.currents) and a.stamp_ns >= zeros[0].stamp_ns]
    assert sum(b - a for a, b in on) <= 1000 * len(pending)
    assert stream.commanded(clock.t) == (0.0,)
    assert stream.done and stream.cancel(clock.t) == []


def test_runner_ticks_at_the_feedback_rate():
    m = motion()
    clock = FakeClock()
    stream = Stream(build_setpoints(m, clock.t + int(0.25 * NS)), lead_time=0.1)
    ticks = []
    StreamRunner(stream, lambda sp: None, clock, clock.sleep, on_tick=ticks.append,
                 tick_period=0.05).run(until_ns=stream.end_ns + int(0.05 * NS))
    gaps = np.diff(ticks) / NS
    assert len(ticks) >= 20 and gaps.max() <= 0.1 + 1e-6   # >= 10 Hz


def test_stream_refuses_unordered_setpoints():
    with pytest.raises(ValueError):
        Stream([Setpoint(10, (1.0,), 0), Setpoint(5, (0.0,), 1)], 0.1)
    with pytest.raises(ValueError):
        Stream([], 0.1)


# --- settling and timing ----------------------------------------------------------------------
def test_settle_detector():
    d = SettleDetector(velocity=1e-3, hold=0.05)
    assert not d.update(0, [0.5])
    assert not d.update(int(0.01 * NS), [0.0])
    assert not d.update(int(0.04 * NS), [0.0])
    assert d.update(int(0.07 * NS), [0.0])
    assert not d.update(int(0.08 * NS), [0.01])     # moving again resets


def test_timing_stats():
    s = timing_stats([0, 1000, 2000], [100_000, 1000 + 200_000, 2000 - 50_000], "bridge")
    assert s.count == 3 and s.source == "bridge"
    assert s.max == pytest.approx(200e-6) and s.p50 == pytest.approx(100e-6)
    empty = timing_stats([], [], "bridge")
    assert empty.count == 0 and math.isnan(empty.p99) and empty.source == "none"


def test_estimate_applied_times_from_measured_current():
    m = motion(currents=[4.0, -2.0, 1.0])
    sps = build_setpoints(m, 0)
    t = np.arange(0, int(1.1 * NS), int(0.001 * NS))
    lag = int(0.0004 * NS)
    measured = [Stream(sps, 0.0).commanded(0) for _ in t]
    st = Stream(sps, 0.0)
    st.due(10 * NS)
    measured = np.array([st.commanded(int(x) - lag) for x in t])
    pairs = estimate_applied_times(sps, t, measured)
    assert len(pairs) == 4                      # 4.0, -2.0, 1.0, 0.0
    for stamp, est in pairs:
        assert 0 < est - stamp <= int(0.0014 * NS)

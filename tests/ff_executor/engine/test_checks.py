"""Engine: configuration and the checks before a move (profile, arm state, start time)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from ff_executor.engine import (NS, EngineConfig, ProfileRejected, check_profile, check_start_state,
                                resolve_start)
from ff_planner.model.profile import CurrentProfile
from tests.ff_executor.engine.common import motion


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

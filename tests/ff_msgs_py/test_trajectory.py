"""ff_msgs_py.trajectory: a CurrentProfile as a JointTrajectory of joint torques (N·m)."""
from __future__ import annotations

import numpy as np
import pytest

from ff_msgs_py.convert import profile_to_msg
from ff_msgs_py.trajectory import SWITCH_EPSILON, duration, effort_at, profile_to_joint_trajectory
from ff_planner.model.params import default_params
from ff_planner.model.profile import CurrentProfile

PROFILE = CurrentProfile(np.array([0.0, 0.2, 0.45, 0.95]), np.array([[2.0, -1.0], [-3.0, 0.5], [1.0, 0.0]]),
                         tf=1.0, coast=0.05)
KT = [0.03, 0.02]       # N·m/A
GEAR = [50.0, 20.0]


def test_effort_is_joint_torque_and_a_controller_sampling_it_replays_the_steps():
    msg = profile_to_msg(PROFILE, "scara2", [0.0, 0.0], [0.5, 0.1], ["shoulder", "elbow"])
    traj = profile_to_joint_trajectory(msg, KT, GEAR)
    assert list(traj.joint_names) == ["shoulder", "elbow"]
    gain = np.array(KT) * np.array(GEAR)
    ticks = np.arange(0.0, 1.2, 1e-3)             # a 1 kHz controller interpolating linearly
    ticks = ticks[np.min(np.abs(ticks[:, None] - PROFILE.step_times[None, :]), axis=1) >= SWITCH_EPSILON]
    want = np.array([PROFILE.current_at(t) for t in ticks]) * gain
    np.testing.assert_allclose(effort_at(traj, ticks), want, atol=1e-12)
    np.testing.assert_allclose(effort_at(traj, 0.3), PROFILE.currents[1] * gain)
    times = [p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec for p in traj.points]
    assert times == sorted(times) and len(set(times)) == len(times)     # strictly increasing
    assert len(traj.points) == 1 + 2 * PROFILE.n_steps + 1
    assert times[-1] == pytest.approx(1.0) and list(traj.points[-1].effort) == [0.0, 0.0]
    # both points of a switch: the old torque just before, the new one at it
    assert times[1] == pytest.approx(0.2 - SWITCH_EPSILON, abs=1e-9) and times[2] == pytest.approx(0.2)
    np.testing.assert_allclose(traj.points[1].effort, PROFILE.currents[0] * gain)
    np.testing.assert_allclose(traj.points[2].effort, PROFILE.currents[1] * gain)
    assert not traj.points[0].positions


def test_one_dof_plan_with_the_arm_constants_and_nominal_states():
    p = default_params("arm1dof")
    prof = CurrentProfile.uniform([[1.0], [-1.0]], 1.0)
    states = []
    traj = profile_to_joint_trajectory(prof, p.kt, p.n, joint_names=["joint1"],
                                       state_at=lambda t: (states.append(t) or [t], [0.0]), start_ns=5_000_000_001)
    assert traj.points[0].effort[0] == pytest.approx(p.n * p.kt)          # N·m at the joint for 1 A
    assert [p_.positions[0] for p_ in traj.points] == pytest.approx(states)
    assert (traj.header.stamp.sec, traj.header.stamp.nanosec) == (5, 1)


@pytest.mark.parametrize("kw, text", [
    (dict(torque_constant=[0.03]), None),
    (dict(torque_constant=[0.03, 0.02, 0.01]), "torque_constant"),
    (dict(torque_constant=0.03, gear_ratio=float("nan")), "gear_ratio"),
    (dict(torque_constant=0.03, switch_epsilon=0.2), "switch_epsilon"),
    (dict(torque_constant=0.03, switch_epsilon=0.0), "switch_epsilon"),
    (dict(torque_constant=0.03, joint_names=["a"]), "joint names"),
])
def test_bad_arguments_say_what_to_change(kw, text):
    msg = profile_to_msg(PROFILE, "scara2", [0.0, 0.0], [0.5, 0.1])
    if text is None:
        assert len(profile_to_joint_trajectory(msg, **kw).points) == 8      # one constant for both joints
        return
    with pytest.raises(ValueError, match=text):
        profile_to_joint_trajectory(msg, **kw)
    with pytest.raises(ValueError, match="joint_names"):
        profile_to_joint_trajectory(PROFILE, 0.03)


def test_duration_to_the_nanosecond():
    d = duration(1.2345678915)
    assert (d.sec, d.nanosec) == (1, 234567892)
    with pytest.raises(ValueError):
        duration(-1e-3)

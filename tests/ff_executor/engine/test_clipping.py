"""Clipping from the bridge's status: which joints, and only the motion that began after the goal."""
from __future__ import annotations

from ff_executor.engine.clipping import clipped_joints, clipping_message


def test_counts_of_this_motion_are_reported_and_an_earlier_motions_are_not():
    since = 5_000_000_000
    values = {"joint1.motion_limited_count": "3", "joint1.motion_limited_first_ns": str(since + 250_000_000),
              "joint2.motion_limited_count": "7", "joint2.motion_limited_first_ns": str(since - 1),
              "joint3.motion_limited_count": "0", "joint3.motion_limited_first_ns": "0"}
    clips = clipped_joints(values, ["joint1", "joint2", "joint3"], since)
    assert [(c.joint, c.count) for c in clips] == [("joint1", 3)]     # joint2's is an older motion
    text = clipping_message(clips, since + 200_000_000, 0.01)
    assert "statusword bit 11" in text and "joint1: 3 feedback sample(s) (~30 ms) from +0.050 s" in text


def test_a_count_without_a_stamp_counts_and_bad_values_do_not():
    clips = clipped_joints({"j.motion_limited_count": "2", "k.motion_limited_count": "x"}, ["j", "k", "m"], 10)
    assert [(c.joint, c.count, c.first_ns) for c in clips] == [("j", 2, 0)]
    assert "j: 2 feedback sample(s)" in clipping_message(clips, 0, 0.0)

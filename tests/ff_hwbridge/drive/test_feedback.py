"""SamplePairing places a TPDO at its SYNC only when the pairing is certain; JointFeedback is an
immutable snapshot."""
from __future__ import annotations

import dataclasses

import pytest

from ff_hwbridge.drive.feedback import JointFeedback, SamplePairing

P = 10_000_000


def test_one_pending_sync_is_the_one_answered():
    s = SamplePairing(P)
    assert s.on_sync(100 * P) is None
    assert s.on_tpdo(100 * P + 300_000) == 100 * P


def test_a_late_tpdo_is_not_stamped_with_the_next_sync():
    s = SamplePairing(P)
    s.on_sync(100 * P)
    s.on_sync(101 * P)                 # the answer to the first came after the second SYNC
    late = 101 * P + 200_000
    assert s.on_tpdo(late) == late      # two pending: not certain, its own bus instant
    assert s.on_tpdo(101 * P + 300_000) == 101 * P     # the answer to the second: certain
    s.on_sync(102 * P)
    assert s.on_tpdo(102 * P + 100_000) == 102 * P     # paired again from the next SYNC on


def test_a_lost_tpdo_does_not_shift_the_pairing():
    s = SamplePairing(P)
    s.on_sync(100 * P)                 # its TPDO lost
    s.on_sync(101 * P)
    t = 101 * P + 100_000
    assert s.on_tpdo(t) == t            # two pending: not certain
    s.on_sync(102 * P)
    t = 102 * P + 100_000
    assert s.on_tpdo(t) == t            # again: a TPDO was lost, start again
    s.on_sync(103 * P)
    assert s.on_tpdo(103 * P + 100_000) == 103 * P


def test_a_tpdo_before_its_sync_is_placed_when_the_sync_comes():
    s = SamplePairing(P)
    t = 100 * P + 50_000
    assert s.on_tpdo(t) == t
    assert s.on_sync(100 * P) == 100 * P
    assert s.on_sync(101 * P) is None   # a later SYNC does not move it


def test_every_nth_sync():
    s = SamplePairing(P, every=2)
    s.on_sync(100 * P)
    s.on_sync(101 * P)
    assert s.on_tpdo(101 * P + 10_000) == 101 * P


def test_feedback_is_immutable():
    fb = JointFeedback()
    with pytest.raises(dataclasses.FrozenInstanceError):
        fb.position = 1.0  # type: ignore[misc]

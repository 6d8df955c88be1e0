"""Engine: settle detection."""
from __future__ import annotations

from ff_executor.engine import (NS, SettleDetector)


def test_settle_detector():
    d = SettleDetector(velocity=1e-3, hold=0.05)
    assert not d.update(0, [0.5])
    assert not d.update(int(0.01 * NS), [0.0])
    assert not d.update(int(0.04 * NS), [0.0])
    assert d.update(int(0.07 * NS), [0.0])
    assert not d.update(int(0.08 * NS), [0.01])     # moving again resets

"""Clipping during a move, from the bridge's drive-group status.

A feedforward move only lands if the drive applies the planned current. When a drive limits the
command (EPOS statusword bit 11, *internal limit active*: the current was clipped to its output
limit), the arm got less torque than the plan assumed and its rest position is the model's no
more: the move failed, whatever the arm's final position says.

The bridge counts, per joint and per motion, the feedback TPDOs with bit 11 set and stamps the
first (keys ``<joint>.motion_limited_count`` and ``<joint>.motion_limited_first_ns``, wall ns, in
its ``/diagnostics`` status); the count is cleared when its next motion starts.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Optional, Sequence

COUNT_SUFFIX = ".motion_limited_count"
FIRST_SUFFIX = ".motion_limited_first_ns"


@dataclass(frozen=True)
class Clipping:
    """Per joint: TPDOs with statusword bit 11 in the motion, and the first one's wall ns."""

    joint: str
    count: int
    first_ns: int


def _int(values: Mapping[str, str], key: str) -> Optional[int]:
    try:
        return int(float(values[key]))
    except (KeyError, ValueError, OverflowError):
        return None


def clipped_joints(values: Mapping[str, str], joint_names: Sequence[str], since_ns: int) -> list[Clipping]:
    """The joints the drive clipped in the motion that began after ``since_ns`` (wall ns), from
    one bridge status's key/value map. A count whose first clipped sample is stamped before
    ``since_ns`` belongs to an earlier motion (its record not cleared yet) and is ignored; a
    count without a stamp counts (a clip must not pass unnoticed)."""
    out = []
    for name in joint_names:
        count = _int(values, name + COUNT_SUFFIX)
        if not count or count <= 0:
            continue
        first = _int(values, name + FIRST_SUFFIX) or 0
        if first and first < since_ns:
            continue
        out.append(Clipping(name, count, first))
    return out


def clipping_message(clips: Sequence[Clipping], start_ns: int, sync_period: float) -> str:
    """One line for a result: which joints, how many feedback cycles, from when (s after the
    move's start ``start_ns``, wall ns)."""
    parts = []
    for c in clips:
        when = f" from {(c.first_ns - start_ns) / 1e9:+.3f} s" if c.first_ns else ""
        cycles = f"{c.count} feedback sample(s)"
        if sync_period > 0:
            cycles += f" (~{c.count * sync_period * 1e3:.0f} ms)"
        parts.append(f"{c.joint}: {cycles}{when}")
    return ("the drive clipped the current (statusword bit 11, internal limit active) during the "
            "move, so the arm did not get the planned current: " + "; ".join(parts))

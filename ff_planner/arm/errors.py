"""The one error an arm description (URDF + cell file) is refused with, before any planning."""
from __future__ import annotations

from typing import Optional

from ff_planner.core.errors import ParameterError


class ArmConfigError(ParameterError):
    """A URDF or cell file the suite cannot use. One line naming the file, the joint (if any) and
    the field, e.g. ``cell scara2.yaml: joint 'joint2': motor.kt must be > 0 Nm/A, got -1``.

    ``source``: the file; ``joint``: the joint's name or None; ``field``: the key (dotted)."""

    def __init__(self, source: str, joint: Optional[str], field: str, problem: str) -> None:
        where = f"{source}: " + (f"joint '{joint}': " if joint else "")
        super().__init__(f"{where}{field} {problem}".replace("\n", " "), code="INVALID_REQUEST")
        self.source = source
        self.joint = joint
        self.field = field

"""The planner's exceptions and error names, shared by every layer above.

Error names are those of the ``PlanTrajectory`` service (``ff_msgs/srv/PlanTrajectory.srv``): the
ROS adapter maps a name to the interface constant of the same name, so the numbers live in one
place, the interface.
"""
from __future__ import annotations

#: PlanTrajectory error names, in the order of the interface's constants.
ERROR_NAMES: tuple[str, ...] = ("OK", "INVALID_REQUEST", "UNKNOWN_MODEL", "UNKNOWN_PARAMETER",
                                "UNREACHABLE", "NO_ROBUST_PLAN", "TIME_BUDGET_EXHAUSTED",
                                "INTERNAL_ERROR")


class ParameterError(ValueError):
    """A parameter name or value that the model cannot accept; the message says what to change.

    ``code`` is the PlanTrajectory error name: UNKNOWN_MODEL, UNKNOWN_PARAMETER or INVALID_REQUEST.
    """

    def __init__(self, message: str, code: str = "INVALID_REQUEST") -> None:
        super().__init__(message)
        self.code = code


class PlanningError(ValueError):
    """A request the planner cannot serve as asked; the message says what to change.

    ``code`` is the PlanTrajectory error name (INVALID_REQUEST, UNREACHABLE, ...).
    """

    def __init__(self, message: str, code: str = "INVALID_REQUEST") -> None:
        super().__init__(message)
        self.code = code


class WarmStartUnavailable(RuntimeError):
    """The planner for this request cannot start from given currents (only a multistart)."""


def error_code_of(exc: BaseException) -> str:
    """PlanTrajectory error name for an exception raised while reading, validating or planning."""
    if isinstance(exc, (PlanningError, ParameterError)):
        return exc.code
    if isinstance(exc, (ValueError, TypeError)):
        return "INVALID_REQUEST"
    return "INTERNAL_ERROR"

"""The planner's bottom layer: exceptions, error names and result types shared by every layer."""
from ff_planner.core.errors import ERROR_NAMES, ParameterError, PlanningError, WarmStartUnavailable, error_code_of
from ff_planner.core.results import SimResult

__all__ = ["ERROR_NAMES", "ParameterError", "PlanningError", "SimResult", "WarmStartUnavailable",
           "error_code_of"]

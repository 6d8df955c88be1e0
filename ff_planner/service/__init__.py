"""The planner node's logic without ROS: request checking, motion library, worker processes."""
from ff_planner.service.planner_service import (PlannerService, RequestFields, ServiceConfig,
                                                ServiceConfigError, config_from_mapping)

__all__ = ["PlannerService", "RequestFields", "ServiceConfig", "ServiceConfigError", "config_from_mapping"]

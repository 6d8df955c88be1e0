"""The planner's ROS 2 node ``ff_planner`` (console script ``ff-planner-node``)."""
from ff_planner.ros.planner_node import PlannerNode, main

__all__ = ["PlannerNode", "main"]

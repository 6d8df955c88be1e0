"""ff_planner: robust feedforward current planning (pure numpy/scipy; no ROS)."""

"""Friction identification from the arm's own motions (no ROS)."""

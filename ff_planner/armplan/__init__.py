"""Robust feedforward plans and certificates for arms from a URDF (ff_planner.arm), n joints."""

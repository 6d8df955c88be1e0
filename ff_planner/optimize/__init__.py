"""Robust feedforward planning: the facade (``check``, ``plan``) and the planners behind it.

``plan(request)`` dispatches by (model, objective) through ``ROUTES``: ``robust1d`` (1-DOF arm,
compiled Levenberg–Marquardt multistart), ``robust2d`` (2-DOF SCARA, one joint held in stiction:
``hold_joint``, ``robust2d_sequential``, ``robust2d_least_worst``, ``robust2d_refine``) and the
time-/energy-optimal ``baselines``, and ``box_robust`` (1-DOF robust-box: least worst rest
error over a friction box). ``certificate`` states any 1-DOF plan's rest error over the box.
``sample_box`` defines the friction samples of the robust-sampled and robust-box objectives, the
certificate and the finite-change verification. Units: rad, A, Nm, s.
"""
from ff_planner.optimize.baselines import (
                                           Baseline,
                                           energy_optimal_1dof,
                                           finite_differences,
                                           plan_baseline,
                                           reach_1dof,
                                           time_optimal_1dof,
)
from ff_planner.optimize.box_robust import plan_box_robust_1dof
from ff_planner.optimize.certificate import certify_1dof
from ff_planner.optimize.planner import ROUTES, CheckedRequest, Route, check, plan, plan_auto_1dof, reach
from ff_planner.optimize.robust1d import plan_robust_1dof, solve_block, verify
from ff_planner.optimize.robust2d import plan_robust_scara2, verify_plan
from ff_planner.optimize.sample_box import FINITE_CHANGES, sample_scales

__all__ = [
    "ROUTES", "Baseline", "CheckedRequest", "FINITE_CHANGES", "Route", "certify_1dof", "check",
    "energy_optimal_1dof", "plan_auto_1dof", "plan_box_robust_1dof",
    "finite_differences", "plan", "plan_baseline", "plan_robust_1dof", "plan_robust_scara2", "reach",
    "reach_1dof", "sample_scales", "solve_block", "time_optimal_1dof", "verify", "verify_plan",
]

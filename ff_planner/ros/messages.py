"""The planner node's message plumbing: PlanTrajectory / PlanMotion fields <-> the service.

``fields_from_msg`` reads a ``PlanTrajectory.Request`` or a ``PlanMotion.Goal`` (the same fields);
``fill_response`` fills a ``PlanTrajectory.Response`` or a ``PlanMotion.Result`` from a
``PlanResult``: the common fields (``ff_msgs_py.convert.result_to_response``), the robustness
certificate (``ff_msgs/RobustnessCertificate``) and ``profile.predicted_rest`` (rad).
``feedback_from_progress`` turns the planner's progress dicts into ``PlanMotion.Feedback``.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Optional

from ff_msgs.msg import RobustnessCertificate as CertificateMsg
from ff_msgs_py.convert import certificate_to_msg, result_to_response
from ff_planner.model.profile import PlanResult, RobustnessCertificate
from ff_planner.service.planner_service import RequestFields


def fields_from_msg(msg: Any) -> RequestFields:
    """PlanTrajectory.Request / PlanMotion.Goal -> RequestFields (plain python)."""
    return RequestFields(
        model=msg.model, q0=list(msg.q0), qf=list(msg.qf), move_time=msg.move_time,
        uncertain=list(msg.uncertain), objective=msg.objective, steps=msg.steps, starts=msg.starts,
        seed=msg.seed, time_budget=msg.time_budget, override_names=list(msg.override_names),
        override_values=list(msg.override_values), box_names=list(msg.box_names),
        box_fractions=list(msg.box_fractions), coast_max=msg.coast_max, switch_grid=msg.switch_grid,
        position_min=list(msg.position_min), position_max=list(msg.position_max),
        velocity_max=list(msg.velocity_max), tolerance=msg.tolerance,
        move_time_max=msg.move_time_max)


def certificate_msg(cert: Optional[RobustnessCertificate]) -> CertificateMsg:
    """RobustnessCertificate -> ff_msgs/RobustnessCertificate (``certified = false`` for None),
    excursion included (``ff_msgs_py.convert.certificate_to_msg``); a drive-exact plan's
    certificate (``DriveCertificate``, its ``drive`` dict) fills drive_exact, the setpoint unit
    (A), the switch period (s) and the configuration they came from."""
    return certificate_to_msg(cert)


def fill_response(result: PlanResult, response: Any) -> Any:
    """Fill a PlanTrajectory.Response or PlanMotion.Result from ``result``; returns it."""
    result_to_response(result, response)
    response.certificate = certificate_msg(result.certificate)
    rest = (result.extra or {}).get("predicted_rest") or []
    if result.profile is not None:
        response.profile.predicted_rest = [float(x) for x in rest]
        names = (result.extra or {}).get("joint_names") or []
        if len(names) == result.profile.n_joints:     # an arm from a URDF: its joints' names
            response.profile.joint_names = [str(x) for x in names]
    return response


def feedback_from_progress(feedback: Any, report: Mapping[str, Any], *, stage: str, starts_total: int,
                           steps: int, elapsed: float) -> Any:
    """Fill a PlanMotion.Feedback from the latest progress ``report`` of the planner (keys
    ``stage``, ``starts_done``, ``best``); ``stage`` is the service's stage when the report has
    none; ``elapsed`` s since the goal was accepted."""
    feedback.stage = str(report.get("stage") or stage)
    feedback.starts_done = max(0, int(report.get("starts_done", 0) or 0))
    feedback.starts_total = max(0, int(starts_total))
    feedback.steps = max(0, int(report.get("n_steps", steps) or 0))
    best = report.get("best")
    feedback.best_cost = float(best) if isinstance(best, (int, float)) and not isinstance(best, bool) \
        else math.inf
    feedback.elapsed = float(elapsed)
    return feedback

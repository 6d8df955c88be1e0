"""Conversions between ff_msgs messages and numpy arrays / the planner's dataclasses.

Pure functions. Times: ``builtin_interfaces/Time`` <-> integer ns. PlanTrajectory error codes:
:data:`ERROR_CODES` maps each name of ``ff_planner.core.errors.ERROR_NAMES`` to the interface
constant of the same name, so the numbers are defined once, in ``srv/PlanTrajectory.srv``.
"""
from __future__ import annotations

import hashlib
import json
import math
from typing import Any, Optional, Sequence

import numpy as np
from builtin_interfaces.msg import Time

from ff_msgs.msg import CurrentProfile as CurrentProfileMsg
from ff_msgs.msg import CurrentSetpoint
from ff_msgs.msg import RobustnessCertificate as CertificateMsg
from ff_msgs.srv import PlanTrajectory
from ff_planner.core.errors import ERROR_NAMES
from ff_planner.model.limits import Excursion, MotionLimits
from ff_planner.model.params import ParameterError, default_params, n_joints
from ff_planner.model.profile import (CurrentProfile, DriveCertificate, PlanRequest, PlanResult,
                                      RobustnessCertificate)


# --- joint names ------------------------------------------------------------------------------
def default_joint_names(model: str, fallback: int) -> list[str]:
    """``joint1 .. jointN``, N = the model's joint count (``fallback`` for an unknown model)."""
    try:
        nj = n_joints(model)
    except ParameterError:
        nj = fallback
    return [f"joint{j + 1}" for j in range(nj)]


# --- time -------------------------------------------------------------------------------------
def time_to_ns(stamp: Any) -> int:
    """builtin_interfaces/Time -> integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def ns_to_time(ns: int):
    """Integer nanoseconds (>= 0) -> builtin_interfaces/Time."""
    ns = int(ns)
    if ns < 0:
        raise ValueError(f"time must be >= 0 ns, got {ns}")
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


# --- profile ----------------------------------------------------------------------------------
def profile_id(profile: CurrentProfile, model: str, q0: Sequence[float] | np.ndarray,
               qf: Sequence[float] | np.ndarray) -> str:
    """A short content hash naming a profile (same motion -> same id)."""
    blob = json.dumps({"m": model, "q0": list(map(float, q0)), "qf": list(map(float, qf)),
                       "t": profile.step_times.tolist(), "i": profile.currents.tolist(),
                       "tf": profile.tf, "c": profile.coast}, sort_keys=True)
    return hashlib.sha1(blob.encode()).hexdigest()[:16]


def profile_to_msg(profile: CurrentProfile, model: str, q0: Sequence[float] | np.ndarray,
                   qf: Sequence[float] | np.ndarray, joint_names: Sequence[str] | None = None,
                   pid: str | None = None,
                   predicted_rest: Sequence[float] | np.ndarray | None = None) -> CurrentProfileMsg:
    """CurrentProfile dataclass -> ff_msgs/msg/CurrentProfile (currents flattened row-major).

    ``predicted_rest`` (rad, one per joint, the model's rest position for this profile) fills the
    message's ``predicted_rest``; None, or a length other than the joint count, leaves it empty
    (= unknown)."""
    names = (list(joint_names) if joint_names is not None
             else default_joint_names(model, profile.n_joints))
    if len(names) != profile.n_joints:
        raise ValueError(f"{len(names)} joint names for a {profile.n_joints}-joint profile")
    rest = [float(x) for x in np.ravel(predicted_rest)] if predicted_rest is not None else []
    return CurrentProfileMsg(
        profile_id=pid or profile_id(profile, model, q0, qf), model=model, joint_names=names,
        q0=[float(x) for x in q0], qf=[float(x) for x in qf],
        step_times=profile.step_times.tolist(), currents=profile.currents.ravel().tolist(),
        n_steps=profile.n_steps, coast=float(profile.coast), move_time=float(profile.tf),
        predicted_rest=rest if len(rest) == profile.n_joints and np.all(np.isfinite(rest)) else [])


def predicted_rest_of(msg: Any) -> list[float]:
    """The profile message's ``predicted_rest`` (rad per joint), [] when unknown (empty, wrong
    length or not finite)."""
    rest = [float(x) for x in getattr(msg, "predicted_rest", [])]
    if len(rest) != len(msg.joint_names) or not all(np.isfinite(rest)):
        return []
    return rest


def msg_to_profile(msg: Any) -> CurrentProfile:
    """ff_msgs/msg/CurrentProfile -> CurrentProfile dataclass; ValueError if inconsistent."""
    nj = len(msg.joint_names)
    n = int(msg.n_steps)
    cur = np.asarray(msg.currents, dtype=float)
    if nj < 1:
        raise ValueError("profile has no joint names")
    if cur.size != n * nj:
        raise ValueError(f"profile has {cur.size} currents, expected n_steps x joints = {n} x {nj}")
    if len(msg.step_times) != n + 1:
        raise ValueError(f"profile has {len(msg.step_times)} step times, expected n_steps + 1 = {n + 1}")
    return CurrentProfile(np.asarray(msg.step_times, dtype=float), cur.reshape(n, nj),
                          float(msg.move_time), float(msg.coast))


# --- setpoints --------------------------------------------------------------------------------
def setpoint_msg(stamp_ns: int, currents: Sequence[float], seq: int, pid: str = "", last: bool = False,
                 token: str = ""):
    """Build ff_msgs/msg/CurrentSetpoint taking effect at ``stamp_ns`` (ROS clock, ns), carrying the
    drive's claim ``token`` ("" = none)."""
    return CurrentSetpoint(stamp=ns_to_time(stamp_ns), currents=[float(c) for c in currents],
                           seq=int(seq), profile_id=pid, last=bool(last), token=str(token))


def setpoint_to_tuple(msg: Any) -> tuple[int, np.ndarray, int, str, bool]:
    """CurrentSetpoint -> (stamp ns, currents A, seq, profile id, last)."""
    return (time_to_ns(msg.stamp), np.asarray(msg.currents, dtype=float), int(msg.seq),
            str(msg.profile_id), bool(msg.last))


# --- plan service -----------------------------------------------------------------------------
def request_to_msg(request: PlanRequest):
    """PlanRequest -> PlanTrajectory.Request (overrides = every parameter that differs from preset)."""
    p = request.resolved_params()
    ref = default_params(request.model).to_dict()
    over = {k: v for k, v in p.to_dict().items() if v != ref[k]}
    limits = request.limits or MotionLimits()
    box = dict(request.box or {})
    return PlanTrajectory.Request(
        model=request.model, q0=[float(x) for x in request.q0], qf=[float(x) for x in request.qf],
        move_time=float(request.tf), uncertain=list(request.uncertain), objective=request.objective,
        steps=int(request.steps or 0), starts=int(request.starts), seed=int(request.seed),
        time_budget=float(request.time_budget), override_names=list(over),
        override_values=list(over.values()), box_names=list(box),
        box_fractions=[float(v) for v in box.values()],
        coast_max=float(request.coast_max) if request.coast_max != PlanRequest().coast_max else 0.0,
        position_min=[float(x) for x in limits.position_min],
        position_max=[float(x) for x in limits.position_max],
        velocity_max=[float(x) for x in limits.velocity_max],
        tolerance=float(request.tolerance or 0.0),
        move_time_max=float(request.move_time_max or 0.0) if request.tolerance else 0.0)


#: PlanTrajectory error name -> the interface constant of that name (PlanTrajectory.Response).
ERROR_CODES: dict[str, int] = {name: int(getattr(PlanTrajectory.Response, name)) for name in ERROR_NAMES}


def result_to_response(result: PlanResult, response: Any, joint_names: Sequence[str] | None = None):
    """Fill a PlanTrajectory.Response from a PlanResult; returns the response."""
    response.success = bool(result.success)
    response.error_code = ERROR_CODES.get(result.error_code, ERROR_CODES["INTERNAL_ERROR"])
    response.message = str(result.message)
    if result.profile is not None:
        response.profile = profile_to_msg(result.profile, result.model, result.q0, result.qf, joint_names,
                                          predicted_rest=result.extra.get("predicted_rest"))
    response.q_final = [float(x) for x in np.ravel(result.q_final)]
    response.qd_final = [float(x) for x in np.ravel(result.qd_final)]
    response.sensitivity_names = list(result.sensitivities)
    response.sensitivity_values = [float(v) for v in result.sensitivities.values()]
    response.robust = bool(result.robust)
    response.warm_start = bool(result.warm_start)
    response.starts_tried = int(result.starts_tried)
    response.iterations = int(result.iterations)
    response.solve_time = float(result.solve_time)
    response.certificate = certificate_to_msg(result.certificate)
    return response


def certificate_to_msg(cert: Optional[RobustnessCertificate]) -> CertificateMsg:
    """RobustnessCertificate -> ff_msgs/RobustnessCertificate (``certified = false`` for None;
    the excursion arrays empty when it has none). A drive-exact certificate (``DriveCertificate``,
    its ``drive`` dict) fills ``drive_exact``, the setpoint unit (A), the switch period (s) and
    the configuration they came from; any other leaves them false / 0 / ""."""
    if cert is None:
        return CertificateMsg(certified=False)
    names = list(cert.box)
    msg = CertificateMsg(
        certified=True, box_names=names, box_fractions=[float(cert.box[n]) for n in names],
        worst_rest_error=float(cert.worst_rest_error),
        worst_at=[float(cert.worst_at.get(n, 1.0)) for n in names],
        per_parameter=[float(cert.per_parameter.get(n, math.nan)) for n in names],
        moving_at_tf=float(cert.moving_at_tf), switch_timing=[float(x) for x in cert.switch_timing],
        worst_per_joint=[float(x) for x in (cert.worst_per_joint or [])],
        switch_timing_per_joint=[float(x) for row in (cert.switch_timing_per_joint or []) for x in row],
        samples=int(cert.samples))
    ex = cert.excursion
    if ex is not None:
        for name in _EXCURSION_FIELDS:
            setattr(msg, f"excursion_{name}", [float(x) for x in getattr(ex, name)])
    drive = getattr(cert, "drive", None) or {}
    msg.drive_exact = bool(drive)
    msg.drive_setpoint_unit = float(drive.get("current_quantum_A", 0.0) or 0.0)
    msg.drive_switch_period = float(drive.get("switch_period_s", 0.0) or 0.0)
    msg.drive_source = str(drive.get("source", "") or "")
    return msg


_EXCURSION_FIELDS = ("nominal_min", "nominal_max", "nominal_speed", "worst_min", "worst_max",
                     "worst_speed")


def certificate_from_msg(msg: Any) -> Optional[RobustnessCertificate]:
    """ff_msgs/RobustnessCertificate -> RobustnessCertificate (None when ``certified`` is false).
    The inverse of :func:`certificate_to_msg`; ``switch_timing_per_joint`` comes back as rows of
    one value per joint (the joint count from ``worst_per_joint``). With ``drive_exact`` true it is a
    ``DriveCertificate`` whose ``drive`` holds ``current_quantum_A``, ``switch_period_s`` and
    ``source`` (the message does not carry ``certified_profile``)."""
    if not bool(msg.certified):
        return None
    names = list(msg.box_names)
    nj = len(msg.worst_per_joint)
    flat = [float(x) for x in msg.switch_timing_per_joint]
    rows = [flat[i:i + nj] for i in range(0, len(flat), nj)] if nj else []
    arrays = {name: [float(x) for x in getattr(msg, f"excursion_{name}", [])]
              for name in _EXCURSION_FIELDS}
    excursion = Excursion(**arrays) if any(arrays.values()) else None
    fields: dict[str, Any] = dict(
        box=dict(zip(names, map(float, msg.box_fractions))),
        worst_rest_error=float(msg.worst_rest_error),
        worst_at=dict(zip(names, map(float, msg.worst_at))),
        per_parameter=dict(zip(names, map(float, msg.per_parameter))),
        moving_at_tf=float(msg.moving_at_tf), switch_timing=[float(x) for x in msg.switch_timing],
        samples=int(msg.samples), worst_per_joint=[float(x) for x in msg.worst_per_joint],
        switch_timing_per_joint=rows, excursion=excursion)
    if bool(getattr(msg, "drive_exact", False)):
        drive = {"current_quantum_A": float(msg.drive_setpoint_unit),
                 "switch_period_s": float(msg.drive_switch_period), "source": str(msg.drive_source)}
        return DriveCertificate(drive=drive, **fields)
    return RobustnessCertificate(**fields)


def error_response(response: Any, code: str, message: str):
    """Fill a PlanTrajectory.Response for a refused request (success = false)."""
    response.success = False
    response.error_code = ERROR_CODES.get(code, ERROR_CODES["INTERNAL_ERROR"])
    response.message = message
    return response


def response_to_result(response: Any, request: PlanRequest) -> PlanResult:
    """PlanTrajectory.Response (+ the request it answers) -> PlanResult, e.g. to write a motion file.

    The inverse of :func:`result_to_response`; ``params`` and ``coast`` come from ``request`` (the
    response carries the profile's coast and move time), the error name from the interface
    constant, the certificate (and its excursion) from the response's.
    """
    names = {code: name for name, code in ERROR_CODES.items()}
    prof = msg_to_profile(response.profile) if int(response.profile.n_steps) > 0 else None
    return PlanResult(
        success=bool(response.success), message=str(response.message), profile=prof,
        model=request.model, params=request.resolved_params(), q0=np.asarray(request.q0, dtype=float),
        qf=np.asarray(request.qf, dtype=float), uncertain=list(request.uncertain),
        objective=request.objective, q_final=np.asarray(response.q_final, dtype=float),
        qd_final=np.asarray(response.qd_final, dtype=float),
        sensitivities=dict(zip(response.sensitivity_names, map(float, response.sensitivity_values))),
        robust=bool(response.robust), error_code=names.get(int(response.error_code), "INTERNAL_ERROR"),
        best_effort=prof is not None and not bool(response.success),
        starts_tried=int(response.starts_tried), iterations=int(response.iterations),
        solve_time=float(response.solve_time), warm_start=bool(response.warm_start),
        extra=({"predicted_rest": predicted_rest_of(response.profile)}
               if prof is not None and predicted_rest_of(response.profile) else {}),
        certificate=certificate_from_msg(response.certificate))

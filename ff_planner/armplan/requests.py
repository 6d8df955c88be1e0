"""Plan requests for registered arms from a URDF: the model id ``urdf:NAME``.

A registry maps NAME to its URDF and cell files (the planner's ``arms.NAME.urdf`` /
``arms.NAME.cell`` parameters); :func:`plan_registered` checks a request against the arm and
returns a :class:`~ff_planner.model.profile.PlanResult` (robust-box, ``plan_box_robust_arm``)
whose ``extra`` carries the arm's joint names, the plan's label (zero-derivative / least-worst)
and the predicted rest position; a request with a tolerance (rad) gets the fastest move time
certified within it (``ff_planner.armplan.fastest``). Nothing here raises on a bad request: a
malformed or unknown model id, a bad arm file or a request the arm cannot serve comes back as a
failed PlanResult with one clear message and its error code. Units: rad, A, s.
"""
from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ff_planner.arm.errors import ArmConfigError
from ff_planner.arm.model import UrdfArm, load_arm
from ff_planner.armplan.fastest import plan_fastest_arm
from ff_planner.armplan.robust_box import plan_box_robust_arm, plan_result
from ff_planner.core.errors import ParameterError, PlanningError, error_code_of
from ff_planner.model.profile import PlanResult
from ff_planner.optimize.fastest import DEFAULT_MOVE_TIME_MAX

PREFIX = "urdf:"
PARAM_PREFIX = "arms."
NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_\-]{0,63}$")
OBJECTIVES = ("", "robust-box")


@dataclass(frozen=True)
class RegisteredArm:
    """An arm the planner serves as ``urdf:NAME``: its URDF and cell files (absolute paths)."""

    name: str
    urdf: Path
    cell: Path


def is_urdf_model(model: str) -> bool:
    """True for a model id of the form ``urdf:...`` (well formed or not)."""
    return str(model).strip().startswith(PREFIX)


def registry_from_parameters(values: Mapping[str, Any], resolve: Callable[[str], Path]
                             ) -> dict[str, RegisteredArm]:
    """The ``arms.NAME.urdf`` / ``arms.NAME.cell`` entries of ``values`` -> registry; ``resolve``
    turns a configured path into a file. ValueError naming the parameter for a bad name, a
    missing half, an unknown key or a file that does not exist."""
    parts: dict[str, dict[str, str]] = {}
    for key, value in values.items():
        if not key.startswith(PARAM_PREFIX):
            continue
        rest = key[len(PARAM_PREFIX):].split(".")
        if len(rest) != 2 or rest[1] not in ("urdf", "cell"):
            raise ValueError(f"parameter {key}: expected arms.<NAME>.urdf or arms.<NAME>.cell")
        if not NAME_RE.match(rest[0]):
            raise ValueError(f"parameter {key}: arm name {rest[0]!r} must start with a letter and "
                             "hold only letters, digits, '_' and '-' (at most 64)")
        if not isinstance(value, str) or not value.strip():
            raise ValueError(f"parameter {key}: expected a file path, got {value!r}")
        parts.setdefault(rest[0], {})[rest[1]] = value.strip()
    out = {}
    for name, files in sorted(parts.items()):
        for half in ("urdf", "cell"):
            if half not in files:
                raise ValueError(f"arm {name}: parameter arms.{name}.{half} is missing")
        paths = {}
        for half, text in files.items():
            p = resolve(text)
            if not p.is_file():
                raise ValueError(f"parameter arms.{name}.{half}: no such file {text!r}")
            paths[half] = p
        out[name] = RegisteredArm(name, paths["urdf"], paths["cell"])
    return out


def arm_name(model: str, registry: Mapping[str, RegisteredArm]) -> str:
    """NAME of a ``urdf:NAME`` model id; PlanningError (INVALID_REQUEST / UNKNOWN_MODEL) with the
    registered names for a malformed or unknown one."""
    name = str(model).strip()[len(PREFIX):]
    known = ", ".join(f"{PREFIX}{n}" for n in sorted(registry)) or "none"
    if not NAME_RE.match(name):
        raise PlanningError(f"model id {model!r} is malformed: expected {PREFIX}NAME, NAME a "
                            f"registered arm (registered: {known})", "INVALID_REQUEST")
    if name not in registry:
        raise PlanningError(f"model id {model!r}: no arm named {name!r} is registered "
                            f"(registered: {known}; add arms.{name}.urdf and arms.{name}.cell to "
                            "the planner's parameters)", "UNKNOWN_MODEL")
    return name


_ARMS: dict[tuple[str, str], UrdfArm] = {}


def load_registered(entry: RegisteredArm) -> UrdfArm:
    """The UrdfArm of a registry entry (loaded once per process; ArmConfigError if unusable)."""
    key = (str(entry.urdf), str(entry.cell))
    if key not in _ARMS:
        _ARMS[key] = load_arm(entry.cell, entry.urdf)
    return _ARMS[key]


def _failed(model: str, message: str, code: str, q0: Sequence[float], qf: Sequence[float],
            t0: float) -> PlanResult:
    return PlanResult(success=False, message=message, profile=None, model=model, params=None,
                      q0=np.asarray(q0, float), qf=np.asarray(qf, float), uncertain=[],
                      objective="robust-box", error_code=code,
                      solve_time=time.perf_counter() - t0)


@dataclass(frozen=True)
class ArmRequest:
    """The fields of a plan request a registered arm takes (the rest must be left empty)."""

    model: str
    q0: Sequence[float]
    qf: Sequence[float]
    move_time: float
    objective: str = ""
    steps: int = 0
    seed: int = 0
    time_budget: float = 0.0
    unsupported: tuple[str, ...] = ()      # names of request fields set that arms do not take
    tolerance: float = 0.0                 # rad, > 0: the fastest tf certified within it
    move_time_max: float = 0.0             # s, with a tolerance: the longest tf (0 = default)


def plan_registered(req: ArmRequest, registry: Mapping[str, RegisteredArm], *,
                    default_time_budget: float, max_time_budget: float, max_steps: int,
                    max_move_time: float, coast: float) -> PlanResult:
    """Plan ``req`` for its registered arm (see the module); never raises on bad input."""
    t0 = time.perf_counter()
    try:
        name = arm_name(req.model, registry)
        if req.unsupported:
            raise PlanningError(f"{', '.join(req.unsupported)}: not taken for {req.model} (the "
                                "arm's cell file sets the friction box and limits)")
        if req.objective not in OBJECTIVES:
            raise PlanningError(f"objective {req.objective!r}: arms from a URDF plan robust-box only")
        tol = float(req.tolerance)
        if not (math.isfinite(tol) and tol >= 0.0):
            raise PlanningError(f"tolerance must be >= 0 rad (0 = none), got {tol:g}")
        if tol > 0.0:
            tf_max = float(req.move_time_max) or min(DEFAULT_MOVE_TIME_MAX, max_move_time)
            if not (coast < tf_max <= max_move_time):
                raise PlanningError(f"move_time_max must be in ({coast:g}, {max_move_time:g}] s, "
                                    f"got {tf_max:g}")
        elif float(req.move_time_max):
            raise PlanningError("move_time_max bounds a tolerance search: give a tolerance too")
        tf = float(req.move_time) if tol == 0.0 else tf_max
        if not (0.0 < tf <= max_move_time):
            raise PlanningError(f"move_time must be in (0, {max_move_time:g}] s, got {tf:g}")
        if not (coast < tf):
            raise PlanningError(f"move_time {tf:g} s must exceed the coast {coast:g} s")
        budget = float(req.time_budget) or float(default_time_budget)
        if not (0.0 < budget <= max_time_budget):
            raise PlanningError(f"time_budget must be in (0, {max_time_budget:g}] s, got {budget:g}")
        steps = int(req.steps)
        if steps < 0 or steps > max_steps:
            raise PlanningError(f"steps must be in [0, {max_steps}] (0 = from the box), got {steps}")
        arm = load_registered(registry[name])
        if len(req.q0) != arm.n or len(req.qf) != arm.n:
            raise PlanningError(f"{req.model} moves {arm.n} joints ({', '.join(arm.joints)}): q0 and "
                                f"qf need {arm.n} values each (rad), got {len(req.q0)} and "
                                f"{len(req.qf)}")
        if tol > 0.0:
            found = plan_fastest_arm(arm, list(req.q0), list(req.qf), tol, tf_max=tf_max,
                                     coast=coast, steps=steps or None, seed=int(req.seed),
                                     time_budget=budget, model=req.model)
            found.result.solve_time = time.perf_counter() - t0
            return found.result
        res = plan_box_robust_arm(arm, list(req.q0), list(req.qf), tf, coast=coast,
                                  steps=steps or None, seed=int(req.seed), time_budget=budget)
    except (ArmConfigError, ParameterError, PlanningError, ValueError) as exc:
        code = "INVALID_REQUEST" if isinstance(exc, ArmConfigError) else error_code_of(exc)
        return _failed(req.model, str(exc), code, req.q0, req.qf, t0)
    return plan_result(arm, res, req.model, time.perf_counter() - t0)

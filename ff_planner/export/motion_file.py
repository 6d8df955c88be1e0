"""The suite's motion file, format ``ff-motion/1`` (JSON): write, read, validate, re-check.

Required keys (others may be added and are kept)::

    {"format": "ff-motion/1", "model": "arm1dof" | "scara2",
     "params": {every model parameter, SI units},
     "q0": [..], "qf": [..], "tf": 1.0, "coast": 0.05,
     "step_times": [0.0, ..., tf - coast],          N+1 boundaries, s
     "currents": [[I_joint1, (I_joint2)], ...],     N rows, A
     "uncertain": ["pc", ...],
     "predicted": {"q_final": [..], "qd_final": [..], "sensitivities": {"pc": .., ...}}}

This module also writes ``objective``, ``robust``, ``best_effort``, ``success``, ``message``,
``rest_position`` and ``planner`` (solve statistics) when it has them.

``verify_motion`` re-simulates a file independently of the planner (from the file's own numbers
only), optionally with scaled friction parameters, and reports where the arm ends.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence, Union

import numpy as np

from ff_planner.model.params import MODELS, ParameterError, Params, friction_scaled, n_joints
from ff_planner.model.profile import CurrentProfile, PlanningError, PlanResult
from ff_planner.model.simulate import rest_position, simulate

FORMAT = "ff-motion/1"
REQUIRED_KEYS = ("format", "model", "params", "q0", "qf", "tf", "coast", "step_times",
                 "currents", "uncertain", "predicted")

PathLike = Union[str, Path]


class MotionFileError(ValueError):
    """A motion file that is not valid ff-motion/1; the message names the key and the fix."""


@dataclass
class Motion:
    """A motion file's content, typed. Units: rad, s, A."""

    model: str
    params: Params
    q0: np.ndarray
    qf: np.ndarray
    profile: CurrentProfile
    uncertain: list[str]
    predicted_q_final: np.ndarray
    predicted_qd_final: np.ndarray
    predicted_sensitivities: dict[str, float]
    extra: dict[str, Any] = field(default_factory=dict)   # every other key of the file

    @property
    def tf(self) -> float:
        return self.profile.tf

    @property
    def coast(self) -> float:
        return self.profile.coast


# --- writing -------------------------------------------------------------------------------
def _floats(x: Any) -> list:
    return np.asarray(x, dtype=float).tolist()


def motion_to_dict(result: PlanResult, *, extra: Optional[Mapping[str, Any]] = None) -> dict:
    """The ff-motion/1 mapping for a plan result (raises MotionFileError if it holds no profile)."""
    if result.profile is None or result.params is None:
        raise MotionFileError("the plan result holds no profile/parameters; nothing to write")
    prof = result.profile
    d: dict[str, Any] = {
        "format": FORMAT,
        "model": result.model,
        "params": result.params.to_dict(),
        "q0": _floats(result.q0),
        "qf": _floats(result.qf),
        "tf": float(prof.tf),
        "coast": float(prof.coast),
        "step_times": _floats(prof.step_times),
        "currents": _floats(prof.currents),
        "uncertain": list(result.uncertain),
        "predicted": {
            "q_final": _floats(result.q_final),
            "qd_final": _floats(result.qd_final),
            "sensitivities": {k: float(v) for k, v in result.sensitivities.items()},
        },
        "objective": result.objective,
        "success": bool(result.success),
        "robust": bool(result.robust),
        "best_effort": bool(result.best_effort),
        "error_code": result.error_code,
        "message": result.message,
        "planner": {"starts_tried": int(result.starts_tried), "iterations": int(result.iterations),
                    "solve_time_s": float(result.solve_time), "warm_start": bool(result.warm_start)},
        "units": {"angles": "rad", "time": "s", "current": "A",
                  "sensitivities": "rad per parameter unit (d q(tf) / d p)"},
    }
    rest = result.extra.get("rest_position") if result.extra else None
    if rest is not None:
        d["predicted"]["rest_position"] = _floats(rest)
    if result.extra:
        d["extra"] = jsonable(result.extra)
    cert = getattr(result, "certificate", None)
    if cert is not None:     # rest error over the uncertainty box (see RobustnessCertificate)
        d["certificate"] = jsonable(cert.to_dict())
    if extra:
        d.update(jsonable(dict(extra)))
    validate_motion_dict(d)
    return d


def jsonable(x: Any) -> Any:
    """Convert numpy values and nested containers to plain JSON types (non-finite -> None)."""
    if isinstance(x, Mapping):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(float(x)) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.bool_,)):
        return bool(x)
    if isinstance(x, (str, int, bool)) or x is None:
        return x
    return str(x)


def write_motion(path: PathLike, result: PlanResult, *,
                 extra: Optional[Mapping[str, Any]] = None) -> Path:
    """Write a plan result as an ff-motion/1 JSON file; returns the path."""
    d = motion_to_dict(result, extra=extra)
    p = Path(path)
    if p.parent and not p.parent.exists():
        raise MotionFileError(f"folder {str(p.parent)!r} does not exist; create it or choose "
                              f"another output path")
    p.write_text(json.dumps(d, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    return p


# --- reading and validation ----------------------------------------------------------------
def _vector(d: Mapping[str, Any], key: str, length: Optional[int] = None) -> np.ndarray:
    v = d[key]
    if not isinstance(v, list) or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                          for x in v):
        raise MotionFileError(f"'{key}' must be a list of numbers, got {v!r}")
    a = np.asarray(v, dtype=float)
    if not np.all(np.isfinite(a)):
        raise MotionFileError(f"'{key}' must hold finite numbers, got {v!r}")
    if length is not None and a.shape[0] != length:
        raise MotionFileError(f"'{key}' needs {length} value(s), got {a.shape[0]}")
    return a


def _number(d: Mapping[str, Any], key: str) -> float:
    v = d[key]
    if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(float(v)):
        raise MotionFileError(f"'{key}' must be a finite number, got {v!r}")
    return float(v)


def validate_motion_dict(d: Any) -> Motion:
    """Check a parsed ff-motion/1 mapping; return it as a Motion or raise MotionFileError."""
    if not isinstance(d, Mapping):
        raise MotionFileError("a motion file must hold a JSON object")
    missing = [k for k in REQUIRED_KEYS if k not in d]
    if missing:
        raise MotionFileError(f"missing key(s) {missing}; ff-motion/1 needs {list(REQUIRED_KEYS)}")
    if d["format"] != FORMAT:
        raise MotionFileError(f"'format' is {d['format']!r}; this reader understands {FORMAT!r}")
    model = d["model"]
    if model not in MODELS:
        raise MotionFileError(f"unknown model {model!r}; known models: {', '.join(MODELS)}")
    nj = n_joints(model)
    if not isinstance(d["params"], Mapping):
        raise MotionFileError("'params' must be an object of parameter name -> SI value")
    cls = MODELS[model]
    absent = [k for k in cls.keys() if k not in d["params"]]
    if absent:
        raise MotionFileError(f"'params' lacks {absent}; a motion file lists every parameter of "
                              f"model '{model}'")
    try:
        params = cls().replace(**dict(d["params"]))
    except ParameterError as e:
        raise MotionFileError(f"'params': {e}") from None
    q0 = _vector(d, "q0", nj)
    qf = _vector(d, "qf", nj)
    tf = _number(d, "tf")
    coast = _number(d, "coast")
    times = _vector(d, "step_times")
    cur_raw = d["currents"]
    if not isinstance(cur_raw, list) or not cur_raw:
        raise MotionFileError("'currents' must be a non-empty list of rows (one per step)")
    rows = []
    for i, row in enumerate(cur_raw):
        if not isinstance(row, list) or len(row) != nj or not all(
                isinstance(x, (int, float)) and not isinstance(x, bool) for x in row):
            raise MotionFileError(f"'currents' row {i} must be a list of {nj} number(s), got {row!r}")
        rows.append([float(x) for x in row])
    currents = np.asarray(rows, dtype=float)
    if times.shape[0] != currents.shape[0] + 1:
        raise MotionFileError(f"'step_times' needs N+1 = {currents.shape[0] + 1} boundaries for "
                              f"{currents.shape[0]} current rows, got {times.shape[0]}")
    if not tf > coast >= 0.0:
        raise MotionFileError(f"need tf > coast >= 0, got tf = {tf}, coast = {coast}")
    profile = CurrentProfile(times, currents, tf, coast)
    i_max = [params.i_max] if nj == 1 else [params.i_max1, params.i_max2]
    try:
        profile.validate(i_max)
    except PlanningError as e:
        raise MotionFileError(f"profile: {e}") from None
    unc = d["uncertain"]
    if not isinstance(unc, list) or not all(isinstance(u, str) for u in unc):
        raise MotionFileError(f"'uncertain' must be a list of parameter names, got {unc!r}")
    bad = [u for u in unc if u not in cls.keys()]
    if bad:
        raise MotionFileError(f"'uncertain' names unknown parameter(s) {bad}; valid: "
                              f"{', '.join(cls.keys())}")
    pred = d["predicted"]
    if not isinstance(pred, Mapping) or not {"q_final", "qd_final", "sensitivities"} <= set(pred):
        raise MotionFileError("'predicted' must hold q_final, qd_final and sensitivities")
    pq = _vector(pred, "q_final", nj)
    pqd = _vector(pred, "qd_final", nj)
    sens = pred["sensitivities"]
    if not isinstance(sens, Mapping):
        raise MotionFileError("'predicted.sensitivities' must be an object name -> number")
    sens_f: dict[str, float] = {}
    for k, v in sens.items():
        pname = k.split("/")[-1]
        if pname not in cls.keys():
            raise MotionFileError(f"sensitivity key {k!r} names no parameter of model '{model}'")
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            raise MotionFileError(f"sensitivity {k!r} must be a number, got {v!r}")
        sens_f[k] = float(v)
    extra = {k: v for k, v in d.items() if k not in REQUIRED_KEYS}
    return Motion(model, params, q0, qf, profile, list(unc), pq, pqd, sens_f, extra)


def read_motion(path: PathLike) -> Motion:
    """Read and validate an ff-motion/1 file (MotionFileError with the reason if invalid)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise MotionFileError(f"cannot read motion file {str(p)!r}: {e.strerror or e}") from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as e:
        raise MotionFileError(f"{str(p)!r} is not valid JSON: {e.msg} at line {e.lineno}") from None
    return validate_motion_dict(d)


# --- independent re-check ------------------------------------------------------------------
@dataclass
class MotionCheck:
    """Result of re-simulating a motion file. Units: rad, rad/s."""

    scale: dict[str, float]          # friction scaling applied, e.g. {"pc": 1.1}
    q_final: np.ndarray              # at tf with the scaled parameters
    qd_final: np.ndarray
    rest_position: np.ndarray        # where the arm comes to rest after tf (zero current)
    error: np.ndarray                # q_final - qf
    rest_error: np.ndarray           # rest_position - qf
    nominal_q_final: np.ndarray      # at tf with the file's own parameters
    prediction_mismatch: float       # max |nominal q_final - predicted q_final|
    sensitivities: dict[str, float]  # central differences, recomputed here (rel. step 1e-6)

    @property
    def max_error(self) -> float:
        return float(np.max(np.abs(self.error)))

    @property
    def max_rest_error(self) -> float:
        return float(np.max(np.abs(self.rest_error)))


def _central_sensitivities(params: Params, profile: CurrentProfile, q0: np.ndarray,
                           names: Sequence[str], rel_step: float = 1e-6) -> dict[str, float]:
    """d q(tf) / d p by central differences through simulate() (rad per parameter unit)."""
    out: dict[str, float] = {}
    nj = profile.n_joints
    for name in names:
        p0 = float(getattr(params, name))
        h = rel_step * max(abs(p0), 1e-3)
        qp = simulate(params.replace(**{name: p0 + h}), profile, q0).q_f
        qm = simulate(params.replace(**{name: p0 - h}), profile, q0).q_f
        d = (np.asarray(qp) - np.asarray(qm)) / (2 * h)
        if nj == 1:
            out[name] = float(d[0])
        else:
            for j in range(nj):
                out[f"q{j + 1}/{name}"] = float(d[j])
    return out


def verify_motion(source: Union[PathLike, Motion], scale: Optional[Mapping[str, float]] = None,
                  *, sensitivities: bool = True) -> MotionCheck:
    """Re-simulate a motion file from its own numbers, with friction parameters scaled by ``scale``.

    ``scale={"pc": 1.1, "pv": 0.9}`` = Coulomb friction +10 %, viscous −10 %. Uses only the file
    (not the planner's state), so it is an independent check of the prediction it carries.
    """
    m = source if isinstance(source, Motion) else read_motion(source)
    scale = {str(k): float(v) for k, v in (scale or {}).items()}
    unknown = [k for k in scale if k not in m.params.keys()]
    if unknown:
        raise MotionFileError(f"scale: unknown parameter(s) {unknown} for model '{m.model}'; "
                              f"valid keys: {', '.join(m.params.keys())}")
    try:
        pert = friction_scaled(m.params, scale) if scale else m.params
    except ParameterError as e:
        raise MotionFileError(f"scale: {e}") from None
    nominal = simulate(m.params, m.profile, m.q0)
    sim = simulate(pert, m.profile, m.q0) if scale else nominal
    rest = np.asarray(rest_position(pert, m.profile, m.q0), dtype=np.float64)
    q_f = np.asarray(sim.q_f, dtype=float)
    sens = (_central_sensitivities(m.params, m.profile, m.q0, m.uncertain)
            if sensitivities and m.uncertain else {})
    return MotionCheck(
        scale=scale, q_final=q_f, qd_final=np.asarray(sim.qd_f, dtype=float),
        rest_position=rest, error=q_f - m.qf, rest_error=rest - m.qf,
        nominal_q_final=np.asarray(nominal.q_f, dtype=float),
        prediction_mismatch=float(np.max(np.abs(np.asarray(nominal.q_f) - m.predicted_q_final))),
        sensitivities=sens)

"""Measured runs of the 1-DOF arm: (t, q, current) samples plus the commanded current profile.

A :class:`RunRecord` holds one identification run from rest to rest: sample times t (s, 0 = the
profile's first step), joint positions q (rad, as measured: encoder-quantised), measured motor
current (A) and, when known, the commanded :class:`CurrentProfile`. ``q_resolution`` (rad) is the
position quantum of the encoder (2π / (counts per motor revolution · gear ratio)); 0 = unknown.

Record files (``ff-identify-records/1``, JSON) hold the model's fixed parameters (J, kt, n, i_max
in SI) and a list of runs; ``ff-identify --records FILE`` fits them.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

import numpy as np

from ff_planner.core.errors import ParameterError
from ff_planner.model.params import Arm1DofParams
from ff_planner.model.profile import CurrentProfile

FORMAT = "ff-identify-records/1"


@dataclass
class RunRecord:
    """One run: t (s), q (rad), current (A, measured), the commanded profile, encoder quantum (rad)."""

    t: np.ndarray
    q: np.ndarray
    current: np.ndarray
    profile: Optional[CurrentProfile] = None
    q_resolution: float = 0.0

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float).reshape(-1)
        self.q = np.asarray(self.q, dtype=float).reshape(-1)
        self.current = np.asarray(self.current, dtype=float).reshape(-1)
        self.q_resolution = float(self.q_resolution)

    def validate(self) -> None:
        """Raise ParameterError if the samples are inconsistent or too few."""
        n = self.t.size
        if n < 10:
            raise ParameterError(f"a run needs at least 10 samples, got {n}")
        if self.q.size != n or self.current.size != n:
            raise ParameterError(f"t, q and current need the same length, got {n}, {self.q.size}, "
                                 f"{self.current.size}")
        if not (np.all(np.isfinite(self.t)) and np.all(np.isfinite(self.q))):
            raise ParameterError("t and q must be finite")
        if np.any(np.diff(self.t) <= 0.0):
            raise ParameterError("sample times must increase strictly")
        if self.profile is not None:
            self.profile.validate()
            if self.profile.n_joints != 1:
                raise ParameterError(f"a 1-DOF run needs a 1-joint profile, got {self.profile.n_joints}")
        if not math.isfinite(self.q_resolution) or self.q_resolution < 0.0:
            raise ParameterError(f"q_resolution must be >= 0 rad, got {self.q_resolution}")

    def input_profile(self) -> CurrentProfile:
        """The current that drove the run: the commanded profile, else a zero-order hold of the
        measured current samples from t = 0 on (less exact: switch times to within one sample)."""
        if self.profile is not None:
            return self.profile
        keep = self.t >= 0.0
        t, i = self.t[keep], np.nan_to_num(self.current[keep])
        if t.size < 2:
            raise ParameterError("a run without a profile needs current samples from t = 0 on")
        times = np.concatenate([[0.0], t[1:]]) if t[0] > 0.0 else t
        return CurrentProfile(times, i[:-1].reshape(-1, 1), float(t[-1]), 0.0)

    @property
    def duration(self) -> float:
        """s of the run from the first step to the last sample (the arm's motion time)."""
        return float(self.t[-1] - max(0.0, float(self.t[0])))

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"t": self.t.tolist(), "q": self.q.tolist(),
                               "current": self.current.tolist(), "q_resolution": self.q_resolution}
        if self.profile is not None:
            p = self.profile
            out["profile"] = {"step_times": p.step_times.tolist(), "currents": p.currents[:, 0].tolist(),
                              "tf": p.tf, "coast": p.coast}
        return out

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "RunRecord":
        try:
            prof = None
            if d.get("profile"):
                p = d["profile"]
                prof = CurrentProfile(np.asarray(p["step_times"], float), np.asarray(p["currents"], float),
                                      float(p["tf"]), float(p.get("coast", 0.0)))
            rec = cls(np.asarray(d["t"], float), np.asarray(d["q"], float),
                      np.asarray(d.get("current", np.full(len(d["t"]), np.nan)), float), prof,
                      float(d.get("q_resolution", 0.0)))
        except (KeyError, TypeError, ValueError) as exc:
            raise ParameterError(f"bad run record: {exc}") from None
        rec.validate()
        return rec


def save_records(path: str | Path, runs: Sequence[RunRecord], params: Arm1DofParams,
                 meta: Optional[Mapping[str, Any]] = None) -> None:
    """Write runs to an ``ff-identify-records/1`` JSON file (params: the arm's fixed values)."""
    data = {"format": FORMAT, "model": params.model, "params": params.to_dict(),
            "meta": dict(meta or {}), "runs": [r.to_dict() for r in runs]}
    Path(path).write_text(json.dumps(data))


def load_records(path: str | Path) -> tuple[list[RunRecord], Arm1DofParams, dict[str, Any]]:
    """(runs, parameters of the arm, meta) from an ``ff-identify-records/1`` file."""
    try:
        data = json.loads(Path(path).read_text())
    except OSError as exc:
        raise ParameterError(f"cannot read {path}: {exc.strerror}") from None
    except json.JSONDecodeError as exc:
        raise ParameterError(f"{path} is not JSON: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ParameterError(f"{path} is not an {FORMAT} file (key 'format')")
    if data.get("model", "arm1dof") != "arm1dof":
        raise ParameterError(f"identification supports model 'arm1dof' only, got {data.get('model')!r}")
    params = Arm1DofParams.from_dict(data.get("params") or {})
    runs = [RunRecord.from_dict(r) for r in data.get("runs") or []]
    if not runs:
        raise ParameterError(f"{path} holds no runs")
    return runs, params, dict(data.get("meta") or {})

"""The planner's data types: a piecewise-constant current profile, a plan request and its result.

These are what the library, the CLI, the motion file, the ROS messages (via ff_msgs_py) and the
executor exchange. Units: s, A, rad, rad/s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

from ff_planner.core.errors import PlanningError
from ff_planner.model.limits import Excursion, MotionLimits
from ff_planner.model.params import ParameterError, Params, default_params, n_joints

DEFAULT_COAST = 0.05  # s, zero-current coast at the end of every move (paper section 4.1.1)

OBJECTIVES = ("robust-derivative", "robust-sampled", "robust-box", "time-optimal",
              "energy-optimal")
DEFAULT_COAST_MAX = 0.25   # s, robust-box: longest coast the planner may choose
MAX_TF = 60.0              # s, longest move time a request may ask for
DEFAULT_STARTS = 50        # multistart count when a request leaves starts at 0 (non-robust)
BOX_DEFAULT_STEPS = 12     # robust-box steps when a request leaves them unset (1-DOF paper task,
#                            seeds 0-19: worst rest error median 2.25 mrad in ~0.5-0.7 s, against
#                            7.2 mrad at N = 8 and ~130 mrad at N = 5)


@dataclass
class CurrentProfile:
    """Piecewise-constant motor currents: step i holds ``currents[i]`` on [step_times[i], step_times[i+1]).

    After ``step_times[-1]`` (= tf − coast) the current is zero until ``tf`` and beyond.
    """

    step_times: np.ndarray          # s, shape (N+1,), step_times[0] = 0
    currents: np.ndarray            # A, shape (N, n_joints)
    tf: float                       # s, move time
    coast: float = DEFAULT_COAST    # s

    def __post_init__(self) -> None:
        self.step_times = np.asarray(self.step_times, dtype=float).reshape(-1)
        cur = np.asarray(self.currents, dtype=float)
        if cur.ndim == 1:
            cur = cur.reshape(-1, 1)
        self.currents = cur
        self.tf = float(self.tf)
        self.coast = float(self.coast)

    @property
    def n_steps(self) -> int:
        return int(self.currents.shape[0])

    @property
    def n_joints(self) -> int:
        return int(self.currents.shape[1])

    @classmethod
    def uniform(cls, currents: Sequence[Sequence[float]] | np.ndarray, tf: float,
                coast: float = DEFAULT_COAST) -> "CurrentProfile":
        """Equal-length steps filling [0, tf − coast] (the paper's parameterisation)."""
        cur = np.asarray(currents, dtype=float)
        if cur.ndim == 1:
            cur = cur.reshape(-1, 1)
        times = np.linspace(0.0, tf - coast, cur.shape[0] + 1)
        return cls(times, cur, tf, coast)

    def current_at(self, t: float) -> np.ndarray:
        """Currents (A) commanded at time t (s); zero before 0 and after tf − coast."""
        if t < self.step_times[0] or t >= self.step_times[-1]:
            return np.zeros(self.n_joints)
        i = int(np.searchsorted(self.step_times, t, side="right") - 1)
        return self.currents[min(i, self.n_steps - 1)].copy()

    def validate(self, i_max: Sequence[float] | None = None) -> None:
        """Raise PlanningError if the profile is malformed or exceeds the current limits (A)."""
        if self.step_times.shape[0] != self.n_steps + 1:
            raise PlanningError(f"need n_steps + 1 = {self.n_steps + 1} step times, "
                                f"got {self.step_times.shape[0]}")
        if not (np.all(np.isfinite(self.step_times)) and np.all(np.isfinite(self.currents))):
            raise PlanningError("step times and currents must be finite")
        if not math.isfinite(self.tf) or not math.isfinite(self.coast) or self.coast < 0:
            raise PlanningError("tf and coast must be finite, coast >= 0")
        if abs(self.step_times[0]) > 1e-12 or np.any(np.diff(self.step_times) <= 0):
            raise PlanningError("step times must start at 0 and increase strictly")
        if self.step_times[-1] > self.tf - self.coast + 1e-9:
            raise PlanningError(f"last step ends at {self.step_times[-1]:.6g} s, after "
                                f"tf - coast = {self.tf - self.coast:.6g} s")
        if i_max is not None:
            lim = np.asarray(i_max, dtype=float).reshape(1, -1)
            if np.any(np.abs(self.currents) > lim + 1e-9):
                raise PlanningError(f"currents exceed the limit {lim.ravel().tolist()} A")


@dataclass
class PlanRequest:
    """What to plan. ``params`` None = the model's paper preset."""

    model: str = "arm1dof"
    q0: Sequence[float] = (0.0,)             # rad
    qf: Sequence[float] = (1.0,)             # rad
    tf: float = 1.0                          # s
    uncertain: Sequence[str] = ("pv", "pc", "pt")
    objective: str = "robust-box"
    steps: Optional[int] = None              # per joint; None = 2 + k (robust-box 12,
    #                                          BOX_DEFAULT_STEPS; others only while 12 has none); 0 = chosen
    starts: int = 50                         # 0 = chosen (1-DOF robust planners)
    seed: int = 0
    time_budget: float = 30.0                # s
    coast: float = DEFAULT_COAST             # s
    params: Optional[Params] = None
    tol: float = 1e-6                        # robustness tolerance on |dq(tf)/dp| and |q(tf) - qf|
    box: Optional[dict[str, float]] = None   # ± fraction per uncertain parameter (default 0.2)
    coast_max: float = DEFAULT_COAST_MAX     # s, robust-box: coast chosen in [coast, coast_max]
    current_quantum: float = 0.0             # A, round the plan's currents to this grid (0 = none)
    limits: Optional[MotionLimits] = None    # position range / speed limit along the whole motion
    tolerance: Optional[float] = None        # rad, certified worst rest error wanted: the planner
    #                                          searches the fastest tf <= move_time_max meeting it
    move_time_max: Optional[float] = None    # s, longest tf a tolerance search may choose

    @property
    def auto_steps(self) -> bool:
        """steps = 0: the robust 1-DOF planner chooses the smallest N that works."""
        return self.steps is not None and int(self.steps) == 0

    @property
    def auto_starts(self) -> bool:
        """starts = 0: the robust 1-DOF planner escalates the multistart count."""
        return int(self.starts) == 0

    def resolved_params(self) -> Params:
        return self.params if self.params is not None else default_params(self.model)

    def n_steps(self) -> int:
        """Steps per joint: ``steps``, or when unset 2 + k (robust-box: BOX_DEFAULT_STEPS)."""
        if self.steps:
            return int(self.steps)
        if self.objective == "robust-box":
            return max(BOX_DEFAULT_STEPS, 2 + len(self.uncertain))
        return 2 + len(self.uncertain)

    def box_coast_max(self) -> float:
        """robust-box: the longest coast (s) it may choose — ``coast_max``; left at its default
        on a move no longer than that, half the move time (never below ``coast``)."""
        if self.coast_max == DEFAULT_COAST_MAX and self.tf <= self.coast_max:
            return max(float(self.coast), 0.5 * float(self.tf))
        return float(self.coast_max)

    def validate(self) -> None:
        """Raise PlanningError/ParameterError with what to change; changes nothing."""
        nj = n_joints(self.model)
        p = self.resolved_params()
        if p.model != self.model:
            raise PlanningError(f"parameters are for model '{p.model}', request is for '{self.model}'")
        for name, v in (("q0", self.q0), ("qf", self.qf)):
            if len(v) != nj:
                raise PlanningError(f"{name} needs {nj} value(s) for model '{self.model}', got {len(v)}")
            if not all(math.isfinite(float(x)) for x in v):
                raise PlanningError(f"{name} must be finite, got {list(v)}")
        for name, x in (("tf", self.tf), ("coast", self.coast), ("time_budget", self.time_budget),
                        ("coast_max", self.coast_max), ("current_quantum", self.current_quantum)):
            if not math.isfinite(float(x)):
                raise PlanningError(f"{name} must be finite, got {x}")
        if self.current_quantum < 0.0:
            raise PlanningError(f"current_quantum must be >= 0 A (0 = none), got "
                                f"{self.current_quantum}")
        if not 0.0 < self.tf <= MAX_TF:
            raise PlanningError(f"move time tf must be in (0, {MAX_TF:g}] s, got {self.tf:g}")
        if self.coast < 0:
            raise PlanningError(f"coast must be >= 0 s, got {self.coast}")
        if self.tf <= self.coast:
            raise PlanningError(f"move time tf = {self.tf} s must exceed the coast of {self.coast} s")
        if self.objective == "robust-box" and not self.coast <= self.box_coast_max() < self.tf:
            raise PlanningError(f"robust-box needs coast <= coast_max < tf, got coast = "
                                f"{self.coast} s, coast_max = {self.coast_max} s, tf = {self.tf} s")
        if self.objective not in OBJECTIVES:
            raise PlanningError(f"unknown objective {self.objective!r}; use one of {', '.join(OBJECTIVES)}")
        bad = [u for u in self.uncertain if u not in p.friction_keys]
        if bad:
            raise ParameterError(f"unknown uncertain parameter(s) {bad} for model '{self.model}'; "
                                 f"choose from {', '.join(p.friction_keys)}", code="UNKNOWN_PARAMETER")
        if len(set(self.uncertain)) != len(self.uncertain):
            raise PlanningError(f"uncertain parameters repeat: {list(self.uncertain)}")
        n = self.n_steps()
        if not 1 <= n <= 200 or (self.steps is not None and int(self.steps) < 0):
            raise PlanningError(f"steps per joint must be between 1 and 200 (0: chosen), got "
                                f"{self.steps}")
        if self.starts < 0 or self.starts > 100000:
            raise PlanningError(f"starts must be between 1 and 100000 (0: chosen), got "
                                f"{self.starts}")
        if self.box is not None:
            if not isinstance(self.box, dict):
                raise PlanningError(f"box must map uncertain parameters to fractions, got "
                                    f"{self.box!r}")
            extra = [k for k in self.box if k not in self.uncertain]
            if extra:
                raise PlanningError(f"box names parameter(s) {extra} that are not uncertain; "
                                    f"uncertain are {list(self.uncertain)}")
            for k, f in self.box.items():
                if isinstance(f, bool) or not isinstance(f, (int, float)) \
                        or not math.isfinite(float(f)) or not 0.0 < float(f) < 1.0:
                    raise PlanningError(f"box fraction of {k} must be a number in (0, 1), "
                                        f"got {f!r}")
        if self.time_budget <= 0:
            raise PlanningError(f"time_budget must be > 0 s, got {self.time_budget}")
        if self.limits is not None:
            self.limits.validate(nj, self.q0, self.qf)
        if self.tolerance is not None and not (math.isfinite(float(self.tolerance))
                                               and float(self.tolerance) > 0.0):
            raise PlanningError(f"tolerance must be > 0 rad, got {self.tolerance}")
        if self.move_time_max is not None and not 0.0 < float(self.move_time_max) <= MAX_TF:
            raise PlanningError(f"move_time_max must be in (0, {MAX_TF:g}] s, got "
                                f"{self.move_time_max}")


@dataclass
class GridPlanRequest(PlanRequest):
    """A PlanRequest whose switch times the robust 1-DOF planners put on a grid of ``grid`` s
    (None = anywhere): a drive's SYNC period (the facade, ``planner.on_drive_grid``) or a motion
    library's switch grid."""

    grid: Optional[float] = None


@dataclass
class RobustnessCertificate:
    """How far a plan's rest position strays over an uncertainty box (judged on the exact
    model, zero current after tf until the arm stops).

    box: ± fraction per uncertain parameter. worst_rest_error (rad): largest |rest − qf| found
    (samples, then local ascent from the worst ones), at ``worst_at`` (parameter → scale
    factor). per_parameter: the same with each parameter alone. moving_at_tf: fraction of the
    uniform samples still moving at tf. switch_timing (rad per 100 µs): change of the rest
    position when switch j (the start of step j + 1, the last one the start of the coast) comes
    100 µs late, by central differences (±10 µs) on the nominal model. samples: points
    simulated. Multi-joint plans (SCARA) also carry worst_per_joint (rad, each joint's own
    worst |rest − qf| over the box) and switch_timing_per_joint (rad per 100 µs, rows per
    switch, columns per joint); their worst_rest_error / per_parameter are the largest joint
    error and switch_timing per switch the joint change of largest magnitude (signed).
    """

    box: dict[str, float]
    worst_rest_error: float
    worst_at: dict[str, float]
    per_parameter: dict[str, float]
    moving_at_tf: float
    switch_timing: list[float]
    samples: int
    switch_timing_method: str = "central difference, ±10 us, nominal parameters"
    worst_per_joint: list[float] = field(default_factory=list)
    switch_timing_per_joint: list[list[float]] = field(default_factory=list)
    excursion: Optional[Excursion] = None    # where the arm goes, nominal and over the box

    def to_dict(self) -> dict:
        """JSON-able form (the motion file's ``certificate``); the per-joint figures only for a
        multi-joint plan."""
        units = {"worst_rest_error": "rad", "per_parameter": "rad", "worst_at": "scale factor",
                 "switch_timing_per_100us": "rad"}
        d: dict = {"box": dict(self.box), "worst_rest_error": float(self.worst_rest_error),
                   "worst_at": dict(self.worst_at), "per_parameter": dict(self.per_parameter),
                   "moving_at_tf": float(self.moving_at_tf),
                   "switch_timing_per_100us": [float(x) for x in self.switch_timing],
                   "switch_timing_method": self.switch_timing_method,
                   "samples": int(self.samples), "units": units}
        if self.worst_per_joint:
            d["worst_per_joint"] = [float(x) for x in self.worst_per_joint]
            units["worst_per_joint"] = "rad"
        if self.switch_timing_per_joint:
            d["switch_timing_per_joint_per_100us"] = [[float(x) for x in row]
                                                      for row in self.switch_timing_per_joint]
            units["switch_timing_per_joint_per_100us"] = "rad"
        if self.excursion is not None:
            d["excursion"] = self.excursion.to_dict()
        return d


@dataclass
class DriveCertificate(RobustnessCertificate):
    """A certificate computed on the profile exactly as the drive applies it: ``drive`` says so
    (quantum A, switch period s, source, ``certified_profile``)."""

    drive: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["drive"] = dict(self.drive)
        return d


@dataclass
class PlanResult:
    """A planned motion and how it was found. ``robust`` is judged on true derivatives."""

    success: bool                    # a plan meeting the objective's tolerances was found
    message: str
    profile: Optional[CurrentProfile]
    model: str
    params: Optional[Params]
    q0: np.ndarray
    qf: np.ndarray
    uncertain: list[str]
    objective: str
    q_final: np.ndarray = field(default_factory=lambda: np.zeros(0))     # rad, at tf, nominal
    qd_final: np.ndarray = field(default_factory=lambda: np.zeros(0))    # rad/s, at tf, nominal
    sensitivities: dict[str, float] = field(default_factory=dict)        # "pc" or "q1/pc2" -> rad per unit
    robust: bool = False             # every |sensitivity| <= tol (true derivatives)
    error_code: str = "OK"           # PlanTrajectory error name when not successful
    best_effort: bool = False        # returned plan did not meet tolerances (labelled as such)
    starts_tried: int = 0
    iterations: int = 0
    solve_time: float = 0.0          # s
    warm_start: bool = False
    extra: dict = field(default_factory=dict)   # objective-specific figures (e.g. sampled RMS)
    certificate: Optional[RobustnessCertificate] = None   # rest error over the box

"""Model parameters of the paper's arms, as dataclasses with named presets and YAML loading.

Units are SI throughout: kg, m, kg·m², Nm/A, A, Nm, Nm·s/rad; ``pt`` is a fraction (0.22 = 22 %).
Parameter keys are the motion-file keys: 1-DOF ``J, kt, n, i_max, pv, pc, pt``; 2-DOF the same
per joint with suffix 1/2 plus the link geometry ``m, l, lc, Jc``.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, ClassVar, Mapping, Union

import yaml

from ff_planner.core.errors import ParameterError


@dataclass(frozen=True)
class _ParamsBase:
    """Parameters of one model: ``model`` is its id, ``n_joints`` its number of joints."""

    model: ClassVar[str] = ""
    n_joints: ClassVar[int] = 0
    friction_keys: ClassVar[tuple[str, ...]] = ()
    #: friction keys a plan treats as uncertain unless a request names its own
    default_uncertain: ClassVar[tuple[str, ...]] = ()
    #: s, largest fixed step of the model's ``advance`` that the simulated drive can use without
    #: integration error (the 1-DOF plant is solved in closed form; the SCARA one integrates)
    plant_step: ClassVar[float] = 1e-4

    @classmethod
    def keys(cls) -> tuple[str, ...]:
        """All parameter keys of this model, in declaration order."""
        return tuple(f.name for f in fields(cls))

    def to_dict(self) -> dict[str, float]:
        """Every parameter as ``{key: float}`` in SI units (the motion file's ``params``)."""
        return {k: float(getattr(self, k)) for k in self.keys()}

    @classmethod
    def from_dict(cls, values: Mapping[str, Any], *, base: "_ParamsBase | None" = None):
        """Build from a mapping; keys missing from ``values`` come from ``base`` (default preset)."""
        start = base if base is not None else cls()
        return start.replace(**dict(values))

    def replace(self, **overrides: Any):
        """A copy with some parameters changed; unknown keys and non-finite values are refused."""
        valid = self.keys()
        unknown = [k for k in overrides if k not in valid]
        if unknown:
            raise ParameterError(
                f"unknown parameter(s) {', '.join(map(repr, unknown))} for model "
                f"'{self.model}'; valid keys are: {', '.join(valid)}", code="UNKNOWN_PARAMETER")
        clean: dict[str, float] = {}
        for k, v in overrides.items():
            try:
                x = float(v)
            except (TypeError, ValueError):
                raise ParameterError(f"parameter '{k}' must be a number, got {v!r}") from None
            if not math.isfinite(x):
                raise ParameterError(f"parameter '{k}' must be finite, got {x}")
            clean[k] = x
        out = dataclasses.replace(self, **clean)
        out.validate()
        return out

    def validate(self) -> None:
        """Refuse physically meaningless values (non-positive inertia, limits, gear ratios...)."""
        for f in fields(self):
            x = getattr(self, f.name)
            if not math.isfinite(x):
                raise ParameterError(f"parameter '{f.name}' must be finite, got {x}")
        for k in self._positive_keys():
            if getattr(self, k) <= 0.0:
                raise ParameterError(f"parameter '{k}' must be > 0, got {getattr(self, k)}")
        for k in self._nonnegative_keys():
            if getattr(self, k) < 0.0:
                raise ParameterError(f"parameter '{k}' must be >= 0, got {getattr(self, k)}")

    def _positive_keys(self) -> tuple[str, ...]:
        return ()

    def _nonnegative_keys(self) -> tuple[str, ...]:
        return ()


@dataclass(frozen=True)
class Arm1DofParams(_ParamsBase):
    """1-DOF arm in the horizontal plane (paper table 2 by default)."""

    model: ClassVar[str] = "arm1dof"
    n_joints: ClassVar[int] = 1
    friction_keys: ClassVar[tuple[str, ...]] = ("pv", "pc", "pt")
    default_uncertain: ClassVar[tuple[str, ...]] = ("pv", "pc", "pt")
    plant_step: ClassVar[float] = 1e-3

    J: float = 0.17        # kg·m², inertia about the joint (all inertia combined)
    kt: float = 0.0267     # Nm/A, motor torque constant
    n: float = 54.0        # gear ratio (joint torque = n · kt · I)
    i_max: float = 10.0    # A, current limit
    pv: float = -0.05      # Nm·s/rad, viscous friction
    pc: float = 0.19       # Nm, Coulomb friction
    pt: float = 0.22       # torque-dependent friction, fraction of |n·kt·I|

    @property
    def torque_per_amp(self) -> float:
        """Nm of joint torque per A of motor current (n · kt)."""
        return self.n * self.kt

    def _positive_keys(self) -> tuple[str, ...]:
        return ("J", "kt", "n", "i_max")

    def _nonnegative_keys(self) -> tuple[str, ...]:
        return ("pc", "pt")


@dataclass(frozen=True)
class Scara2Params(_ParamsBase):
    """2-DOF SCARA arm of paper section 4.2 / table 3, in absolute joint angles.

    Motor 2 drives the absolute angle of link 2 through a parallel mechanism; friction acts on the
    absolute joint velocities; there is no friction between the links.
    """

    model: ClassVar[str] = "scara2"
    n_joints: ClassVar[int] = 2
    friction_keys: ClassVar[tuple[str, ...]] = ("pv1", "pc1", "pt1", "pv2", "pc2", "pt2")
    default_uncertain: ClassVar[tuple[str, ...]] = ("pc1", "pc2")
    plant_step: ClassVar[float] = 1e-4

    pv1: float = -0.05     # Nm·s/rad
    pv2: float = -0.14     # Nm·s/rad
    pc1: float = 0.19      # Nm
    pc2: float = 0.60      # Nm
    pt1: float = 0.22      # fraction
    pt2: float = 0.32      # fraction
    Jc1: float = 0.023     # kg·m², link 1 inertia about its centre of mass
    Jc2: float = 0.178     # kg·m², link 2 inertia about its centre of mass
    m1: float = 0.809      # kg
    m2: float = 1.502      # kg
    l1: float = 0.41       # m, link 1 length (joint 1 to joint 2)
    l2: float = 0.43       # m
    lc1: float = 0.07      # m, joint 1 to the centre of mass of link 1
    lc2: float = 0.33      # m, joint 2 to the centre of mass of link 2
    kt1: float = 0.0267    # Nm/A
    kt2: float = 0.0281    # Nm/A
    n1: float = 54.0       # gear ratio
    n2: float = 198.0      # gear ratio
    i_max1: float = 10.0   # A
    i_max2: float = 10.0   # A

    def _positive_keys(self) -> tuple[str, ...]:
        return ("Jc1", "Jc2", "m1", "m2", "l1", "l2", "kt1", "kt2", "n1", "n2", "i_max1", "i_max2")

    def _nonnegative_keys(self) -> tuple[str, ...]:
        return ("pc1", "pc2", "pt1", "pt2", "lc1", "lc2")


Params = Union[Arm1DofParams, Scara2Params]

#: model id → its parameter class
MODELS: dict[str, type[_ParamsBase]] = {cls.model: cls for cls in (Arm1DofParams, Scara2Params)}

#: Named parameter sets from the paper.
PRESETS: dict[str, Params] = {
    "table1": Arm1DofParams(pv=0.0, pc=0.19, pt=0.0),   # Coulomb-only arm, section 3.2
    "table2": Arm1DofParams(),                           # full friction model, section 4.1
    "table3": Scara2Params(),                            # 2-DOF SCARA, section 4.2
}
DEFAULT_PRESET: dict[str, str] = {"arm1dof": "table2", "scara2": "table3"}


def n_joints(model: str) -> int:
    """Number of joints of a model id."""
    return MODELS[check_model(model)].n_joints


def check_model(model: str) -> str:
    """Return ``model`` if it is known, else raise ParameterError naming the known ones."""
    if model not in MODELS:
        raise ParameterError(f"unknown model {model!r}; known models: {', '.join(MODELS)}",
                             code="UNKNOWN_MODEL")
    return model


def default_params(model: str) -> Params:
    """The paper's parameters for a model id (table 2 for arm1dof, table 3 for scara2)."""
    return PRESETS[DEFAULT_PRESET[check_model(model)]]


def preset(name: str) -> Params:
    """A named preset ('table1', 'table2', 'table3')."""
    if name not in PRESETS:
        raise ParameterError(f"unknown preset {name!r}; known presets: {', '.join(PRESETS)}",
                             code="UNKNOWN_PARAMETER")
    return PRESETS[name]


def load_params(source: Union[str, Path, Mapping[str, Any]]) -> Params:
    """Parameters from a YAML file or mapping.

    Layout: ``{model: arm1dof, preset: table2, params: {pc: 0.2, ...}}``; ``preset`` defaults to
    the model's paper table, ``params`` overrides individual keys (SI units).
    """
    if isinstance(source, (str, Path)):

        with open(source, "r", encoding="utf-8") as fh:
            data = yaml.safe_load(fh) or {}
    else:
        data = dict(source)
    if not isinstance(data, Mapping):
        raise ParameterError("parameter file must hold a mapping with keys model, preset, params")
    extra = set(data) - {"model", "preset", "params"}
    if extra:
        raise ParameterError(f"unexpected key(s) {sorted(extra)}; expected model, preset, params")
    if "preset" in data:
        base = preset(str(data["preset"]))
        if "model" in data and check_model(str(data["model"])) != base.model:
            raise ParameterError(f"preset {data['preset']!r} is for model '{base.model}', "
                                 f"not '{data['model']}'")
    else:
        base = default_params(str(data.get("model", "arm1dof")))
    return base.replace(**dict(data.get("params") or {}))


def friction_scaled(params: Params, scale: Mapping[str, float]) -> Params:
    """A copy with friction parameters multiplied: ``{"pc": 1.2}`` is Coulomb friction +20 %."""
    unknown = [k for k in scale if k not in params.keys()]
    if unknown:
        raise ParameterError(f"unknown parameter(s) {unknown} for model '{params.model}'; "
                             f"valid keys are: {', '.join(params.keys())}", code="UNKNOWN_PARAMETER")
    return params.replace(**{k: getattr(params, k) * float(s) for k, s in scale.items()})

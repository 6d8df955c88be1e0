"""The cell file: what a URDF does not say about an arm in its cell (YAML).

Per joint: its motor (torque constant kt Nm/A, gear ratio, current limit i_max A, rotor inertia
kg·m² at the motor shaft), the friction law of Eq. 9 (pv Nm·s/rad, pc Nm, pt fraction) on the
coordinate the motor drives, the ± uncertainty box of each friction parameter (fraction of its
nominal value), the motion limits (the keys of ``ff_planner.model.limits.MotionLimits``: rad,
rad/s), whether the joint moves or is held (by a brake or by its motor's current) and at which
position, and which angle the motor drives: ``relative`` (the joint's own angle, the URDF joint
variable) or ``absolute`` (the link's angle from the base, the sum of the joint variables from the
first moving joint to this one: a motor at the base driving the link through a parallel
mechanism, as the paper's SCARA). The cell also gives the mounting: the gravity vector (m/s²) in
the URDF's base frame.

Example (config/arms/scara2.cell.yaml)::

    name: scara2
    urdf: scara2.urdf            # relative to the cell file
    gravity: [0.0, 0.0, -9.81]
    joints:
      joint1:
        motor: {kt: 0.0267, gear: 54, i_max: 10}
        friction: {pv: -0.05, pc: 0.19, pt: 0.22}
        box: {pv: 0.2, pc: 0.2, pt: 0.2}
      joint2:
        angle: absolute
        ...
      wrist: {hold: brake, position: 0.0}

Every check happens here, before planning; a bad value raises ``ArmConfigError`` naming the
joint and the field.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Optional, Union

import yaml

from ff_planner.arm.errors import ArmConfigError
from ff_planner.model.limits import MotionLimits

FRICTION_KEYS = ("pv", "pc", "pt")
#: (low, high, inclusive low, unit) of each motor value
_MOTOR_RANGES = {"kt": (0.0, 10.0, False, "Nm/A"), "gear": (0.0, 1e4, False, ""),
                 "i_max": (0.0, 500.0, False, "A"), "rotor_inertia": (0.0, 1.0, True, "kg·m²")}
_FRICTION_RANGES = {"pv": (-100.0, 100.0, True, "Nm·s/rad"), "pc": (0.0, 1e4, True, "Nm"),
                    "pt": (0.0, 1.0, True, "")}
_HOLD = ("brake", "current")
_ANGLES = ("relative", "absolute")
_JOINT_KEYS = {"motor", "friction", "box", "limits", "angle", "hold", "position", "node_id"}
_TOP_KEYS = {"name", "urdf", "gravity", "joints"}


@dataclass(frozen=True)
class Motor:
    """kt (Nm/A), gear ratio (joint torque = gear·kt·I), i_max (A), rotor_inertia (kg·m², at the
    motor shaft; the joint sees gear²·rotor_inertia)."""

    kt: float
    gear: float
    i_max: float
    rotor_inertia: float = 0.0

    @property
    def torque_per_amp(self) -> float:
        """Nm of joint torque per A (gear·kt), Eq. 8."""
        return self.gear * self.kt

    @property
    def armature(self) -> float:
        """Reflected rotor inertia gear²·rotor_inertia (kg·m²) on the driven coordinate."""
        return self.gear * self.gear * self.rotor_inertia


@dataclass(frozen=True)
class JointCell:
    """One joint of the cell. A moving joint has ``motor`` and ``friction``; a held one has
    ``hold`` ("brake" or "current") and ``position`` (rad)."""

    name: str
    hold: Optional[str] = None
    position: float = 0.0
    motor: Optional[Motor] = None
    friction: dict[str, float] = field(default_factory=dict)
    box: dict[str, float] = field(default_factory=dict)
    limits: dict[str, float] = field(default_factory=dict)
    angle: str = "relative"
    node_id: Optional[int] = None

    @property
    def moves(self) -> bool:
        return self.hold is None


@dataclass(frozen=True)
class Cell:
    """A parsed, checked cell file. ``joints``: by name, in file order; ``urdf``: absolute path."""

    name: str
    source: str
    urdf: Optional[Path]
    gravity: tuple[float, float, float]
    joints: dict[str, JointCell]

    def moving(self) -> list[JointCell]:
        return [j for j in self.joints.values() if j.moves]

    def held(self) -> list[JointCell]:
        return [j for j in self.joints.values() if not j.moves]

    def limits(self, order: list[str]) -> MotionLimits:
        """MotionLimits of the moving joints in ``order`` (a key is kept only when every moving
        joint gives it)."""
        out: dict[str, list[float]] = {}
        for key in ("position_min", "position_max", "velocity_max"):
            vals = [self.joints[n].limits.get(key) for n in order]
            if all(v is not None for v in vals):
                out[key] = [float(v) for v in vals if v is not None]
        return MotionLimits.of(**out)


def _number(src: str, joint: Optional[str], key: str, value: Any) -> float:
    if isinstance(value, bool):
        raise ArmConfigError(src, joint, key, f"must be a number, got {value!r}")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ArmConfigError(src, joint, key, f"must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise ArmConfigError(src, joint, key, f"must be finite, got {value!r}")
    return x


def _ranged(src: str, joint: str, key: str, value: Any, lo: float, hi: float, incl: bool,
            unit: str) -> float:
    x = _number(src, joint, key, value)
    low_ok = x >= lo if incl else x > lo
    if not (low_ok and x <= hi):
        rng = f"{'[' if incl else '('}{lo:g}, {hi:g}]"
        raise ArmConfigError(src, joint, key, f"must be in {rng}{' ' + unit if unit else ''}, "
                                              f"got {x:g}")
    return x


def _mapping(src: str, joint: Optional[str], key: str, value: Any) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise ArmConfigError(src, joint, key, f"must be a mapping, got {type(value).__name__}")
    return value


def _unknown(src: str, joint: Optional[str], prefix: str, got: Mapping[str, Any],
             allowed) -> None:
    for k in got:
        if k not in allowed:
            raise ArmConfigError(src, joint, f"{prefix}{k}", f"is not a known key; use "
                                                             f"{', '.join(sorted(allowed))}")


def _joint(src: str, name: str, raw: Any) -> JointCell:
    d = _mapping(src, name, "(entry)", raw)
    _unknown(src, name, "", d, _JOINT_KEYS)
    node_id = None
    if "node_id" in d:
        node_id_f = _ranged(src, name, "node_id", d["node_id"], 1, 127, True, "")
        if node_id_f != int(node_id_f):
            raise ArmConfigError(src, name, "node_id", f"must be an integer 1..127, got {node_id_f:g}")
        node_id = int(node_id_f)
    if "hold" in d:
        if d["hold"] not in _HOLD:
            raise ArmConfigError(src, name, "hold", f"must be one of {', '.join(_HOLD)}, got "
                                                    f"{d['hold']!r}")
        if "position" not in d:
            raise ArmConfigError(src, name, "position", "is missing (rad, where the held joint stays)")
        motor = None
        if "motor" in d:
            motor = _motor(src, name, d["motor"])
        elif d["hold"] == "current":
            raise ArmConfigError(src, name, "motor", "is missing (a joint held by current needs its motor)")
        return JointCell(name=name, hold=str(d["hold"]),
                         position=_number(src, name, "position", d["position"]), motor=motor,
                         node_id=node_id)
    for key in ("motor", "friction"):
        if key not in d:
            raise ArmConfigError(src, name, key, "is missing (a moving joint needs it; or give "
                                                 "hold: brake|current and position)")
    motor = _motor(src, name, d["motor"])
    fr = _mapping(src, name, "friction", d["friction"])
    _unknown(src, name, "friction.", fr, FRICTION_KEYS)
    friction = {}
    for k in FRICTION_KEYS:
        if k not in fr:
            raise ArmConfigError(src, name, f"friction.{k}", "is missing")
        lo, hi, incl, unit = _FRICTION_RANGES[k]
        friction[k] = _ranged(src, name, f"friction.{k}", fr[k], lo, hi, incl, unit)
    if friction["pt"] >= 1.0:
        raise ArmConfigError(src, name, "friction.pt", f"must be < 1 (a fraction), got {friction['pt']:g}")
    box_raw = _mapping(src, name, "box", d.get("box", {}) or {})
    _unknown(src, name, "box.", box_raw, FRICTION_KEYS)
    box = {k: _ranged(src, name, f"box.{k}", v, 0.0, 0.99, True, "(fraction)")
           for k, v in box_raw.items()}
    lim_raw = _mapping(src, name, "limits", d.get("limits", {}) or {})
    _unknown(src, name, "limits.", lim_raw, ("position_min", "position_max", "velocity_max"))
    limits = {k: _number(src, name, f"limits.{k}", v) for k, v in lim_raw.items()}
    if "velocity_max" in limits and not limits["velocity_max"] > 0.0:
        raise ArmConfigError(src, name, "limits.velocity_max", f"must be > 0 rad/s, got "
                                                               f"{limits['velocity_max']:g}")
    if "position_min" in limits and "position_max" in limits and not (
            limits["position_min"] < limits["position_max"]):
        raise ArmConfigError(src, name, "limits.position_min", f"{limits['position_min']:g} rad "
                                                               f"must be below position_max "
                                                               f"{limits['position_max']:g} rad")
    angle = d.get("angle", "relative")
    if angle not in _ANGLES:
        raise ArmConfigError(src, name, "angle", f"must be relative or absolute, got {angle!r}")
    if "position" in d:
        raise ArmConfigError(src, name, "position", "is only for held joints (hold: brake|current)")
    return JointCell(name=name, motor=motor, friction=friction, box=box, limits=limits,
                     angle=str(angle), node_id=node_id)


def _motor(src: str, name: str, raw: Any) -> Motor:
    m = _mapping(src, name, "motor", raw)
    _unknown(src, name, "motor.", m, _MOTOR_RANGES)
    vals = {}
    for k, (lo, hi, incl, unit) in _MOTOR_RANGES.items():
        if k not in m:
            if k == "rotor_inertia":
                continue
            raise ArmConfigError(src, name, f"motor.{k}", f"is missing ({unit or 'ratio'})")
        vals[k] = _ranged(src, name, f"motor.{k}", m[k], lo, hi, incl, unit)
    return Motor(**vals)


def cell_from_mapping(data: Any, source: str = "cell", base_dir: Optional[Path] = None) -> Cell:
    """Check and build a Cell from parsed YAML; ArmConfigError on the first problem."""
    d = _mapping(source, None, "(file)", data)
    _unknown(source, None, "", d, _TOP_KEYS)
    if "joints" not in d or not d["joints"]:
        raise ArmConfigError(source, None, "joints", "is missing or empty")
    joints_raw = _mapping(source, None, "joints", d["joints"])
    joints = {str(n): _joint(source, str(n), v) for n, v in joints_raw.items()}
    if not any(j.moves for j in joints.values()):
        raise ArmConfigError(source, None, "joints", "has no moving joint (all are held)")
    g_raw = d.get("gravity", [0.0, 0.0, -9.81])
    if not isinstance(g_raw, (list, tuple)) or len(g_raw) != 3:
        raise ArmConfigError(source, None, "gravity", f"must be 3 numbers (m/s², base frame), got {g_raw!r}")
    g = tuple(_number(source, None, "gravity", v) for v in g_raw)
    if math.sqrt(sum(x * x for x in g)) > 30.0:
        raise ArmConfigError(source, None, "gravity", f"magnitude must be <= 30 m/s², got {g}")
    ids = [j.node_id for j in joints.values() if j.node_id is not None]
    for j in joints.values():
        if j.node_id is not None and ids.count(j.node_id) > 1:
            raise ArmConfigError(source, j.name, "node_id", f"{j.node_id} is used by another joint")
    urdf = None
    if "urdf" in d:
        p = Path(str(d["urdf"]))
        urdf = (base_dir / p if base_dir is not None and not p.is_absolute() else p).resolve()
    name = str(d.get("name", Path(source).stem))
    return Cell(name=name, source=source, urdf=urdf, gravity=(g[0], g[1], g[2]), joints=joints)


def load_cell(path: Union[str, Path]) -> Cell:
    """Read and check a cell file (YAML). ArmConfigError when it is missing, unreadable or bad."""
    p = Path(path)
    src = p.name
    try:
        text = p.read_text()
    except OSError as exc:
        raise ArmConfigError(src, None, "(file)", f"cannot be read: {exc.strerror or exc}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ArmConfigError(src, None, "(file)", f"is not valid YAML: {str(exc).splitlines()[0]}") from None
    return cell_from_mapping(data, src, p.parent)

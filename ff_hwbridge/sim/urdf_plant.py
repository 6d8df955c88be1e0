"""The simulated arm for an arm from a URDF plus its cell file (``ff_planner.arm``): any number of
moving joints, Eq. 9 friction on each, one emulated EPOS per joint.

The plant is the planner's own compiled n-joint model (``ff_planner.arm.sim.simulate_core``: RK4
with exact stick/slip events per joint), stepped here under piecewise-constant currents with its
OWN friction (the "true" one, ``UrdfArmParams``), so a test can make the simulated arm differ
from the cell the planner believed. State: the motor angles θ of the moving joints (rad), their
rates (rad/s); currents in A. One call of the kernel advances any interval in sub-steps of
``step`` s, so the plant's clock thread pays one compiled call per tick, not one per sub-step.

The stick/slip mode is carried between calls by the state itself: a joint whose rate is exactly
zero starts a call stuck and the kernel picks the consistent mode (stick, else slide), as it does
after every event inside a call.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Sequence, Union

import numpy as np

from ff_hwbridge.sim.arm import SimArm
from ff_hwbridge.sim.drive import DriveConfig, SimConfigError
from ff_hwbridge.sim.rig import RigConfig
from ff_planner.arm.cell import FRICTION_KEYS
from ff_planner.arm.model import UrdfArm, load_arm
from ff_planner.model.params import ParameterError

__all__ = ["UrdfArmParams", "UrdfRigConfig", "UrdfSimArm", "cell_node_ids", "joint_inertia", "load_plant_arm",
           "urdf_advance"]

#: s, the plant's sub-step: the planner certifies on 4 ms RK4 steps, the plant integrates the same
#: model sixteen times finer, so a landing checks the plan, not one discretisation against itself
#: (arm3h: 19 us of CPU per ms of plant time at 0.25 ms, 47 us at 0.1 ms; the rest positions of a
#: 3-joint move 0.25 ms vs 0.1 ms apart by less than 1e-9 rad)
PLANT_STEP = 2.5e-4
_PER_JOINT = re.compile(r"^(n|kt|i_max)(\d+)$")


def load_plant_arm(cell: Union[str, Path], urdf: Optional[Union[str, Path]] = None) -> UrdfArm:
    """The arm of a cell file (and its URDF, or ``urdf``); SimConfigError with the cell's own
    one-line reason (joint and field) when the suite cannot use it."""
    from ff_planner.arm.errors import ArmConfigError
    try:
        return load_arm(cell, urdf)
    except ArmConfigError as exc:
        raise SimConfigError(str(exc)) from None


@dataclass(frozen=True)
class UrdfArmParams:
    """The simulated arm's true parameters: its ``arm`` (geometry, motors) and the Eq. 9 friction
    of each moving joint, ``friction[j] = (pv Nm·s/rad, pc Nm, pt)``. Keys ``pv1, pc1, pt1, pv2,
    ...`` (joint 1 = the first moving joint, base to tip); ``n1``/``kt1``/``i_max1`` read the
    motors (gear ratio, Nm/A, A)."""

    arm: UrdfArm
    friction: tuple[tuple[float, float, float], ...] = field(default=())
    plant_step: float = PLANT_STEP

    @classmethod
    def of(cls, arm: UrdfArm) -> "UrdfArmParams":
        """The cell's nominal friction."""
        return cls(arm, tuple((float(r[0]), float(r[1]), float(r[2])) for r in arm.friction))

    @property
    def model(self) -> str:
        """The planner's model id of this arm (``urdf:NAME``)."""
        return f"urdf:{self.arm.name}"

    @property
    def n_joints(self) -> int:
        return self.arm.n

    def keys(self) -> tuple[str, ...]:
        return tuple(f"{k}{j + 1}" for j in range(self.arm.n) for k in FRICTION_KEYS)

    def to_dict(self) -> dict[str, float]:
        return {f"{k}{j + 1}": float(self.friction[j][c])
                for j in range(self.arm.n) for c, k in enumerate(FRICTION_KEYS)}

    def replace(self, **overrides: Any) -> "UrdfArmParams":
        """A copy with some friction values changed (``pc2=0.15``); ParameterError naming the key
        on an unknown key or a value Eq. 9 does not take (pc >= 0, 0 <= pt < 1, finite)."""
        rows = [list(r) for r in self.friction]
        for key, value in overrides.items():
            if key not in self.keys():
                raise ParameterError(f"unknown parameter {key!r} for arm '{self.arm.name}'; valid keys "
                                     f"are: {', '.join(self.keys())}", code="UNKNOWN_PARAMETER")
            try:
                x = float(value)
            except (TypeError, ValueError):
                raise ParameterError(f"parameter '{key}' must be a number, got {value!r}") from None
            name, j = key[:2], int(key[2:]) - 1
            if not math.isfinite(x) or (name == "pc" and x < 0.0) or (name == "pt" and not 0.0 <= x < 1.0):
                raise ParameterError(f"parameter '{key}' ({self.arm.joints[j]}) out of range: {x!r} "
                                     "(pc >= 0 Nm, 0 <= pt < 1, finite)")
            rows[j][FRICTION_KEYS.index(name)] = x
        return UrdfArmParams(self.arm, tuple((r[0], r[1], r[2]) for r in rows), self.plant_step)

    def friction_array(self) -> np.ndarray:
        """(3, n) complex rows pv, pc, pt: the kernel's friction argument."""
        return np.ascontiguousarray(np.asarray(self.friction, float).T, dtype=np.complex128)

    def __getattr__(self, name: str) -> float:
        m = _PER_JOINT.match(name)
        if m is None or not 1 <= int(m.group(2)) <= len(self.arm.cells):
            raise AttributeError(name)
        motor = self.arm.cells[int(m.group(2)) - 1].motor
        assert motor is not None     # a moving joint has its motor (ff_planner.arm.cell)
        return float({"n": motor.gear, "kt": motor.kt, "i_max": motor.i_max}[m.group(1)])


def urdf_advance(arm: UrdfArm) -> Callable[..., tuple[np.ndarray, np.ndarray]]:
    """``advance(params, θ, θ̇, currents, dt, *, h) -> (θ, θ̇)`` after ``dt`` s of constant
    currents (A) in RK4 sub-steps of at most ``h`` s with exact events (the planner's kernel),
    under ``params``' friction (a UrdfArmParams of ``arm``)."""
    from ff_planner.arm import sim

    c = arm.constants
    geometry = tuple(np.ascontiguousarray(a, float) for a in (c.Pphi, c.Za, c.Zb, c.Ga, c.Gb, c.armature))
    K = np.ascontiguousarray(arm.torque_per_amp, float)
    n = arm.n
    cache: dict[int, tuple[tuple, np.ndarray]] = {}

    def advance(params: UrdfArmParams, q: np.ndarray, qd: np.ndarray, currents: np.ndarray,
                dt: float, *, h: float = PLANT_STEP) -> tuple[np.ndarray, np.ndarray]:
        if dt <= 0.0:
            return np.asarray(q, float), np.asarray(qd, float)
        key = id(params.friction)
        hit = cache.get(key)
        if hit is None or hit[0] is not params.friction:
            cache.clear()
            hit = (params.friction, params.friction_array())
            cache[key] = hit
        y0 = np.empty(2 * n, dtype=np.complex128)
        y0[:n] = q
        y0[n:] = qd
        cur = np.asarray(currents, dtype=np.complex128).reshape(1, n)
        out = sim.simulate_core(geometry, hit[1], K, np.array([0.0, float(dt)]), cur, cur[0],
                                float(dt), y0, float(min(h, dt)), False, 0.0, 1)
        if out[-1] == sim.CHATTER:
            raise ParameterError(f"arm '{arm.name}': the plant chattered (more than {sim.MAX_EVENTS} "
                                 f"stick/slip events in {dt:g} s)")
        y = out[0]
        return y[:n].real.copy(), y[n:].real.copy()

    return advance


class UrdfSimArm(SimArm):
    """:class:`SimArm` on an arm from a URDF: the plant of ``urdf_advance``, any interval in one
    compiled call (sub-steps of ``step`` s inside)."""

    def __init__(self, params: UrdfArmParams, q0: Sequence[float] | float = 0.0,
                 qd0: Sequence[float] | float | None = None, *, step: float = PLANT_STEP,
                 clock: Optional[Callable[[], int]] = None) -> None:
        import functools
        import time

        adv = functools.partial(urdf_advance(params.arm), h=float(step))
        super().__init__(params, q0, qd0, step=step, advance=adv,        # type: ignore[arg-type]
                         clock=clock or time.monotonic_ns)
        self._own_any_dt = self._any_dt = True


def joint_inertia(arm: UrdfArm, joint: int) -> float:
    """kg·m² a drive's velocity loop is tuned for: the mass matrix's diagonal entry of the joint
    with every later joint at 90° (the arm half folded, as for the SCARA), armature included."""
    theta = np.zeros(arm.n)
    theta[joint + 1:] = math.pi / 2
    return float(arm.constants.mass_matrix(theta)[joint, joint])


@dataclass
class UrdfRigConfig(RigConfig):
    """A rig whose arm comes from a URDF + cell (``urdf_arm``): one drive per moving joint, node
    ids from the cell's ``node_id`` (1..n where the cell gives none), motor data from the cell."""

    urdf_arm: Optional[UrdfArm] = None

    def params(self) -> UrdfArmParams:     # type: ignore[override]
        if self.true_params is not None:
            assert isinstance(self.true_params, UrdfArmParams)
            return self.true_params
        if self.urdf_arm is None:
            raise SimConfigError("a URDF rig needs its arm (urdf_arm)")
        return UrdfArmParams.of(self.urdf_arm)

    def drive_configs(self) -> list[DriveConfig]:
        p = self.params()
        arm, nj = p.arm, p.n_joints
        noms = self._per_drive(nj, f"arm '{arm.name}' has {nj} moving joint(s) {list(arm.joints)}")
        out = []
        for j, nid in enumerate(self.node_ids):
            motor = arm.cells[j].motor
            assert motor is not None
            out.append(DriveConfig(node_id=int(nid), family=self.family, nominal_current=float(noms[j]),
                                   current_limit=float(motor.i_max), torque_constant=float(motor.kt),
                                   counts_per_rev=self.counts_per_rev, gear_ratio=float(motor.gear),
                                   load_inertia=joint_inertia(arm, j),
                                   interpolation_supervision=self.interpolation_supervision))
        return out

    def make_arm(self, q0: Sequence[float], advance: Any = None) -> SimArm:
        if advance is not None:
            return SimArm(self.params(), q0, step=self.step, advance=advance)   # type: ignore[arg-type]
        return UrdfSimArm(self.params(), q0, step=self.step)


def cell_node_ids(arm: UrdfArm) -> list[int]:
    """CANopen node id per moving joint: the cell's ``node_id``, else the joint's number (1..n);
    SimConfigError when two joints end up with one id."""
    ids = [jc.node_id if jc.node_id is not None else j + 1 for j, jc in enumerate(arm.cells)]
    if len(set(ids)) != len(ids):
        raise SimConfigError(f"arm '{arm.name}': node ids {ids} of joints {list(arm.joints)} are not "
                             "all different (give every moving joint its node_id in the cell)")
    return ids

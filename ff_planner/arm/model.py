"""An arm from a URDF plus its cell file: Pinocchio's rigid-body model with the held joints locked,
the motors, Eq. 9 friction per moving joint, and the planar-chain constants of its dynamics.

Coordinates. q: the URDF joint variables of the moving joints (rad), base to tip. θ: the angles
the motors drive (the simulator's state), θ_j = q_j for a ``relative`` joint and θ_j = σ_j·φ_j
for an ``absolute`` one, φ_k = Σ_{i≤k} σ_i·q_i the link's angle from the base about the first
moving axis n (σ_i = ±1: joint i's axis is ±n). So θ = E·q and φ = Pφ·θ with constant E, Pφ.

Dynamics (in θ): M_θ(θ)·θ̈ + b_θ(θ, θ̇) = T − F,  T_j = gear_j·kt_j·I_j (Eq. 8), F_j Eq. 9 on θ̇_j,
M_θ = Pφᵀ·M_φ·Pφ + diag(gear²·J_rotor),  b_θ = Pφᵀ·(c_φ + g_φ).

The moving joints of the arms the compiled simulator takes have parallel axes (a horizontal arm,
a vertical planar arm, any chain whose moving axes are parallel, held joints locked anywhere).
Then, in absolute angles, with complex constants Z_kl (Hermitian) and Γ_k:

    M_φ,kl = Re(Z_kl·e^{i(φ_k − φ_l)}),   c_φ,k = Σ_l Im(Z_kl·e^{i(φ_k − φ_l)})·φ̇_l²,
    g_φ,k = α_k·cos φ_k + β_k·sin φ_k.

The constants are fitted to Pinocchio's own mass matrix (CRBA) and generalized gravity at
random configurations, then the whole model (M, the Coriolis/centrifugal terms by RNEA, gravity)
is checked against Pinocchio at other random states: a relative mismatch above FIT_TOL refuses
the arm (its moving joints are not a parallel-axis chain). Units: rad, rad/s, Nm, kg·m², A.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

import numpy as np

from ff_planner.arm.cell import FRICTION_KEYS, Cell, JointCell, load_cell
from ff_planner.arm.errors import ArmConfigError
from ff_planner.arm.urdf import check_urdf, read_urdf
from ff_planner.model.limits import MotionLimits

FIT_TOL = 1e-9          # relative mismatch of the planar constants against Pinocchio
_FIT_CONFIGS = 16       # random configurations of the fit
_CHECK_STATES = 16      # random states of the check
_AXIS_TOL = 1e-9        # |axis_i × axis_1| above this: not parallel


@dataclass(frozen=True)
class PlanarConstants:
    """The compiled simulator's dynamics constants (see the module docstring).

    Pphi (n, n): φ = Pphi·θ. Za, Zb (n, n): Re, Im of Z. Ga, Gb (n,): α, β of gravity (Nm).
    armature (n,): gear²·J_rotor (kg·m²) on θ."""

    Pphi: np.ndarray
    Za: np.ndarray
    Zb: np.ndarray
    Ga: np.ndarray
    Gb: np.ndarray
    armature: np.ndarray

    def mass_matrix(self, theta: np.ndarray) -> np.ndarray:
        """M_θ (kg·m²) at motor angles θ (rad)."""
        phi = self.Pphi @ theta
        d = phi[:, None] - phi[None, :]
        Mphi = self.Za * np.cos(d) - self.Zb * np.sin(d)
        return self.Pphi.T @ Mphi @ self.Pphi + np.diag(self.armature)

    def bias(self, theta: np.ndarray, theta_d: np.ndarray) -> np.ndarray:
        """b_θ (Nm): Coriolis/centrifugal and gravity torques on θ."""
        phi = self.Pphi @ theta
        w = self.Pphi @ theta_d
        d = phi[:, None] - phi[None, :]
        c = (self.Za * np.sin(d) + self.Zb * np.cos(d)) @ (w * w)
        g = self.Ga * np.cos(phi) + self.Gb * np.sin(phi)
        return self.Pphi.T @ (c + g)


@dataclass(frozen=True)
class UrdfArm:
    """An arm from a URDF and a cell: ``joints`` the moving joints base to tip (the order of the
    currents), ``held`` the locked ones. ``pin_model``: Pinocchio's model of the moving joints
    (held joints locked at their positions, cell gravity). kt·gear, i_max, friction (n, 3) rows
    (pv, pc, pt), box (n, 3) ± fractions (0 = certain). E: θ = E·q. ``constants``: PlanarConstants.
    """

    name: str
    joints: tuple[str, ...]
    held: tuple[str, ...]
    cells: tuple[JointCell, ...]
    torque_per_amp: np.ndarray
    i_max: np.ndarray
    friction: np.ndarray
    box: np.ndarray
    limits: MotionLimits
    gravity: np.ndarray
    E: np.ndarray
    A: np.ndarray
    constants: PlanarConstants
    pin_model: object
    cell: Cell

    @property
    def n(self) -> int:
        return len(self.joints)

    def friction_names(self) -> list[str]:
        """'pv@joint1', ... in the (joint, parameter) order of ``friction``'s rows."""
        return [f"{k}@{j}" for j in self.joints for k in FRICTION_KEYS]

    def q_of_theta(self, theta: np.ndarray) -> np.ndarray:
        """URDF joint variables q (rad) of motor angles θ."""
        return np.linalg.solve(self.E, np.asarray(theta, float))

    def theta_of_q(self, q: np.ndarray) -> np.ndarray:
        return self.E @ np.asarray(q, float)

    def pin_configuration(self, theta: np.ndarray) -> np.ndarray:
        """Pinocchio configuration vector of motor angles θ (continuous joints as cos/sin)."""
        import pinocchio as pin
        m = self.pin_model
        return pin.integrate(m, pin.neutral(m), self.q_of_theta(theta))  # type: ignore[arg-type]

    def holding_torque(self, theta: np.ndarray) -> np.ndarray:
        """Torque (Nm) on θ that holds the arm still at θ against gravity: g_θ(θ)."""
        return self.constants.bias(np.asarray(theta, float), np.zeros(self.n))


def _pin_model(text: str, src: str):
    import pinocchio as pin
    try:
        return pin.buildModelFromXML(text)
    except Exception as exc:    # Pinocchio raises plain RuntimeError/ValueError on bad URDF
        raise ArmConfigError(src, None, "(file)", f"Pinocchio cannot read it: "
                                                  f"{str(exc).splitlines()[0] if str(exc) else exc}") from None


def _reduce(model, cell: Cell, src: str):
    """Lock the held joints at their positions; returns (reduced model, moving names in order)."""
    import pinocchio as pin
    v = np.zeros(model.nv)
    lock = []
    for jc in cell.held():
        jid = model.getJointId(jc.name)
        v[model.joints[jid].idx_v] = jc.position
        lock.append(jid)
    q_ref = pin.integrate(model, pin.neutral(model), v)
    red = pin.buildReducedModel(model, lock, q_ref) if lock else model
    names = [str(red.names[j]) for j in range(1, red.njoints)]
    for j in range(2, red.njoints):
        if red.parents[j] != j - 1:
            raise ArmConfigError(src, names[j - 1], "(structure)", "is not a child of the previous "
                                                                   "moving joint: only serial chains are supported")
    if red.nv != len(names):
        raise ArmConfigError(src, None, "(structure)", "has moving joints with several degrees of "
                                                       "freedom; only revolute joints are supported")
    return red, names


def _axes(model) -> np.ndarray:
    """World-frame axis of each (1-dof) joint at the neutral configuration, (n, 3)."""
    import pinocchio as pin
    data = model.createData()
    q = pin.neutral(model)
    pin.computeJointJacobians(model, data, q)
    out = np.zeros((model.nv, 3))
    for j in range(1, model.njoints):
        Jw = np.asarray(pin.getJointJacobian(model, data, j, pin.ReferenceFrame.WORLD)).reshape(6, -1)
        out[j - 1] = Jw[3:, model.joints[j].idx_v]
    return out


def _fit(model, A: np.ndarray, E: np.ndarray, armature: np.ndarray, names: list[str],
         src: str) -> PlanarConstants:
    import pinocchio as pin
    n = model.nv
    data = model.createData()
    Ainv = np.linalg.inv(A)
    rng = np.random.default_rng(12345)
    qs = rng.uniform(-math.pi, math.pi, size=(_FIT_CONFIGS, n))
    Ms, gs = [], []
    for qv in qs:
        qc = pin.integrate(model, pin.neutral(model), qv)
        M = np.asarray(pin.crba(model, data, qc)).reshape(n, n)
        M = np.triu(M) + np.triu(M, 1).T
        Ms.append(Ainv.T @ M @ Ainv)
        gs.append(Ainv.T @ np.asarray(pin.computeGeneralizedGravity(model, data, qc)).reshape(n))
    phis = qs @ A.T
    Za = np.zeros((n, n))
    Zb = np.zeros((n, n))
    for k in range(n):
        Za[k, k] = float(np.mean([M[k, k] for M in Ms]))
        for l in range(k + 1, n):
            d = phis[:, k] - phis[:, l]
            X = np.column_stack([np.cos(d), -np.sin(d)])
            y = np.array([M[k, l] for M in Ms])
            (a, b), *_ = np.linalg.lstsq(X, y, rcond=None)
            Za[k, l] = Za[l, k] = a
            Zb[k, l] = b
            Zb[l, k] = -b
    Ga = np.zeros(n)
    Gb = np.zeros(n)
    for k in range(n):
        X = np.column_stack([np.cos(phis[:, k]), np.sin(phis[:, k])])
        (Ga[k], Gb[k]), *_ = np.linalg.lstsq(X, np.array([g[k] for g in gs]), rcond=None)
    Pphi = A @ np.linalg.inv(E)
    pc = PlanarConstants(Pphi, Za, Zb, Ga, Gb, np.zeros(n))
    # check the closed form against Pinocchio (mass matrix, RNEA with velocity, gravity) in q
    scale_m = max(float(np.max(np.abs(Za))), 1e-12)
    for _ in range(_CHECK_STATES):
        qv = rng.uniform(-math.pi, math.pi, n)
        vv = rng.uniform(-3.0, 3.0, n)
        qc = pin.integrate(model, pin.neutral(model), qv)
        M = np.asarray(pin.crba(model, data, qc)).reshape(n, n)
        M = np.triu(M) + np.triu(M, 1).T
        tau = np.asarray(pin.rnea(model, data, qc, vv, np.zeros(n))).reshape(n)
        th = E @ qv
        thd = E @ vv
        # the closed form in q: M_q = Eᵀ M_θ E, b_q = Eᵀ b_θ (armature excluded here)
        Mq = E.T @ pc.mass_matrix(th) @ E
        bq = E.T @ pc.bias(th, thd)
        err_m = float(np.max(np.abs(Mq - M))) / scale_m
        scale_b = max(float(np.max(np.abs(tau))), scale_m * 9.0)
        err_b = float(np.max(np.abs(bq - tau))) / scale_b
        if err_m > FIT_TOL or err_b > FIT_TOL:
            raise ArmConfigError(src, None, "(dynamics)", f"do not fit a planar parallel-axis chain "
                                                          f"(relative mismatch {max(err_m, err_b):.1e}); "
                                                          "such arms are not supported yet")
    return PlanarConstants(Pphi, Za, Zb, Ga, Gb, np.asarray(armature, float))


def build_arm(cell: Cell, urdf: Optional[Union[str, Path]] = None) -> UrdfArm:
    """The UrdfArm of a checked cell and its URDF (``urdf`` overrides the cell's ``urdf:``)."""
    import pinocchio as pin
    path = Path(urdf) if urdf is not None else cell.urdf
    if path is None:
        raise ArmConfigError(cell.source, None, "urdf", "is missing (give it in the cell or as --urdf)")
    src = path.name
    info = read_urdf(path)
    check_urdf(info, cell, src)
    full = _pin_model(info.text, src)
    full.gravity.linear = np.array(cell.gravity, float)
    model, names = _reduce(full, cell, src)
    model.gravity.linear = np.array(cell.gravity, float)
    n = len(names)
    axes = _axes(model)
    ref = axes[0] / np.linalg.norm(axes[0])
    sigma = np.ones(n)
    for i in range(n):
        a = axes[i] / np.linalg.norm(axes[i])
        if np.linalg.norm(np.cross(a, ref)) > _AXIS_TOL:
            raise ArmConfigError(src, names[i], "axis", f"{np.round(a, 6).tolist()} is not parallel "
                                                        f"to joint '{names[0]}' axis "
                                                        f"{np.round(ref, 6).tolist()}: moving joints "
                                                        "with non-parallel axes are not supported yet")
        sigma[i] = 1.0 if float(a @ ref) > 0.0 else -1.0
    cells = tuple(cell.joints[nm] for nm in names)
    A = np.zeros((n, n))
    for k in range(n):
        A[k, :k + 1] = sigma[:k + 1]
    E = np.zeros((n, n))
    for j, jc in enumerate(cells):
        if jc.angle == "absolute":
            E[j] = sigma[j] * A[j]
        else:
            E[j, j] = 1.0
    motors = [jc.motor for jc in cells]
    assert all(m is not None for m in motors)
    armature = np.array([m.armature for m in motors if m is not None])
    consts = _fit(model, A, E, armature, names, src)
    fr = np.array([[jc.friction[k] for k in FRICTION_KEYS] for jc in cells])
    box = np.array([[jc.box.get(k, 0.0) for k in FRICTION_KEYS] for jc in cells])
    limits = cell.limits(names)
    del pin
    return UrdfArm(name=cell.name, joints=tuple(names), held=tuple(j.name for j in cell.held()),
                   cells=cells,
                   torque_per_amp=np.array([m.torque_per_amp for m in motors if m is not None]),
                   i_max=np.array([m.i_max for m in motors if m is not None]), friction=fr,
                   box=box, limits=limits, gravity=np.array(cell.gravity, float), E=E, A=A,
                   constants=consts, pin_model=model, cell=cell)


def load_arm(cell_path: Union[str, Path], urdf: Optional[Union[str, Path]] = None) -> UrdfArm:
    """Read a cell file (and its URDF, or ``urdf``), check both, build the arm."""
    return build_arm(load_cell(cell_path), urdf)

"""Drive-exact plans: the profile as a CiA 402 drive applies it, and where its grid comes from.

A drive takes its current setpoint in integer units (an EPOS4 in cyclic synchronous torque mode:
0x6071 in per mille of the motor's rated torque, i.e. nominal current / 1000 per unit; an EPOS2:
1 mA) and, with SYNC-latched setpoints, applies a new one only at a SYNC instant (every
``sync_period`` s). ``DriveGrid`` holds those two numbers: the current quantum (A) and the switch
period (s; 0 = setpoints applied on receipt, no time grid).

``drive_grid_from_config`` reads them from the bridge's own configuration, the same file the
bridge runs with (``config/bridge_*.yaml``, or the bridge node's flat ROS parameters): one
source. The file is read as data (PyYAML); the unit rules mirror
``ff_hwbridge.protocol.units.DriveUnits.current_resolution`` and the bridge's defaults, which the
tests compare.

``snap_times`` puts a profile's switch times on the grid (nearest SYNC, every step at least one
period long); ``latched_times`` is what the bridge does with switch times off the grid (each
setpoint takes effect at the first SYNC at or after its stamp, 10 % of a period tolerance);
``refine_on_quantum`` moves quantised currents by whole quanta to lower the worst rest error over
the certificate's box points. Units: A, s, rad.
"""
from __future__ import annotations

import importlib.util
import math
from dataclasses import dataclass
from dataclasses import replace as dc_replace
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence, Union

import numpy as np
import yaml

from ff_planner.core.errors import PlanningError
from ff_planner.model.arm1dof import FRICTION, TR_REST, track
from ff_planner.model.params import Arm1DofParams
from ff_planner.model.profile import CurrentProfile
from ff_planner.model.profile import DriveCertificate as DriveCertificate  # its home is the model
from ff_planner.optimize.sample_box import box_corners, box_fractions, box_grid, box_uniform

#: the bridge's defaults for keys a bridge config may leave out (ff_hwbridge.drive.config,
#: ff_hwbridge.protocol.units; compared by the tests)
BRIDGE_SYNC_PERIOD = 0.01          # s, BridgeConfig.sync_period
BRIDGE_SETPOINT_TIMING = "sync"    # BridgeConfig.setpoint_timing
BRIDGE_NOMINAL_CURRENT = 3.0       # A, DriveUnits.nominal_current
BRIDGE_FAMILY = "epos4"
EPOS2_UNIT = 0.001                 # A, EPOS2 current mode setpoint (0x2030, mA)
LATCH_TOLERANCE = 0.1              # periods: the bridge assigns a stamp this early to its SYNC
REFINE_UNIFORM = 128               # seeded uniform box points of the quantum refinement
REFINE_SEED = 7
REFINE_MAX_EVALS = 600             # rest-error evaluations of the quantum refinement, at most
REFINE_REACH = 2                   # quanta a refined current may lie from its nearest rounding


class DriveConfigError(ValueError):
    """A bridge configuration the planner cannot take its grid from; the message says why."""


@dataclass(frozen=True)
class DriveGrid:
    """What a drive applies: currents in multiples of ``quantum`` (A) at multiples of ``period``
    (s, the SYNC period; 0 = applied on receipt, no time grid). ``source`` names the
    configuration it came from."""

    quantum: float
    period: float
    source: str = ""

    def __post_init__(self) -> None:
        q, t = float(self.quantum), float(self.period)
        if not (math.isfinite(q) and 0.0 < q < 1.0):
            raise DriveConfigError(f"drive current quantum must be in (0, 1) A, got {self.quantum}")
        if not (math.isfinite(t) and 0.0 <= t < 1.0):
            raise DriveConfigError(f"drive switch period must be in [0, 1) s (0 = no grid), got "
                                   f"{self.period}")
        object.__setattr__(self, "quantum", q)
        object.__setattr__(self, "period", t)

    def describe(self) -> str:
        """One line: '3 mA steps at a 10 ms SYNC (config/bridge_epos4_1dof.yaml)'."""
        when = f"at a {self.period * 1e3:g} ms SYNC" if self.period > 0.0 else "applied on receipt"
        src = f" ({self.source})" if self.source else ""
        return f"{self.quantum * 1e3:g} mA steps {when}{src}"

    def to_dict(self) -> dict:
        return {"current_quantum_A": self.quantum, "switch_period_s": self.period,
                "source": self.source}


# --- the grid from the bridge's configuration -------------------------------------------------
def _number(value: Any, what: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise DriveConfigError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v <= 0.0:
        raise DriveConfigError(f"{what} must be a finite number > 0, got {value!r}")
    return v


def _unit(family: Any, nominal_current: Any, where: str) -> float:
    """The setpoint unit (A) of one joint: EPOS4 nominal current / 1000, EPOS2 1 mA."""
    fam = str(family).lower()
    if fam == "epos4":
        return _number(nominal_current, f"{where} nominal_current (A)") / 1000.0
    if fam == "epos2":
        return EPOS2_UNIT
    raise DriveConfigError(f"{where} family must be epos4 or epos2, got {family!r}")


def _joint_units(data: Mapping[str, Any]) -> list[float]:
    """Setpoint units (A) of every joint of a bridge config, either form."""
    if "joints" in data:
        joints = data["joints"]
        if not isinstance(joints, list) or not joints:
            raise DriveConfigError("joints must be a non-empty list")
        out = []
        for i, j in enumerate(joints):
            if not isinstance(j, Mapping):
                raise DriveConfigError(f"joints[{i}] must be a mapping")
            units = j.get("units") or {}
            if not isinstance(units, Mapping):
                raise DriveConfigError(f"joints[{i}].units must be a mapping")
            out.append(_unit(j.get("family", BRIDGE_FAMILY),
                             units.get("nominal_current", BRIDGE_NOMINAL_CURRENT),
                             f"joints[{i}]"))
        return out
    fams, noms = data.get("families"), data.get("nominal_currents")
    if not isinstance(fams, list) or not fams:
        raise DriveConfigError("the bridge config names no joints (YAML 'joints:' or the node's "
                               "'families:' / 'nominal_currents:' parameters)")
    if noms is None:
        noms = [BRIDGE_NOMINAL_CURRENT] * len(fams)
    if not isinstance(noms, list) or len(noms) != len(fams):
        raise DriveConfigError(f"nominal_currents needs one value per joint ({len(fams)})")
    return [_unit(f, n, f"joint {i + 1}") for i, (f, n) in enumerate(zip(fams, noms))]


def drive_grid_from_mapping(data: Mapping[str, Any], source: str = "") -> DriveGrid:
    """The DriveGrid of a parsed bridge config: the bridge YAML (``sync_period``,
    ``setpoint_timing``, ``joints[].family`` / ``units.nominal_current``) or the bridge node's
    parameters (``ff_hwbridge: ros__parameters:`` with ``families``, ``nominal_currents``).
    Keys left out take the bridge's defaults. Raises DriveConfigError."""
    if not isinstance(data, Mapping):
        raise DriveConfigError(f"a bridge config must be a mapping, got {type(data).__name__}")
    node = data.get("ff_hwbridge")
    if isinstance(node, Mapping) and isinstance(node.get("ros__parameters"), Mapping):
        data = node["ros__parameters"]
    units = _joint_units(data)
    if max(units) - min(units) > 1e-12:
        raise DriveConfigError(f"the joints' setpoint units differ ({', '.join(f'{u * 1e3:g} mA' for u in units)}); "
                               f"the planner takes one current quantum for all joints")
    timing = str(data.get("setpoint_timing", BRIDGE_SETPOINT_TIMING))
    if timing not in ("sync", "on_receipt"):
        raise DriveConfigError(f"setpoint_timing must be sync or on_receipt, got {timing!r}")
    period = (_number(data.get("sync_period", BRIDGE_SYNC_PERIOD), "sync_period (s)")
              if timing == "sync" else 0.0)
    return DriveGrid(quantum=units[0], period=period, source=source)


def _suite_config_dirs() -> list[Path]:
    """The suite's config folders: a source checkout's config/, then the installed data folder."""
    out = [Path(__file__).resolve().parents[2] / "config"]
    spec = importlib.util.find_spec("ff_msgs_py")
    if spec is not None and spec.origin:
        out.append(Path(spec.origin).parent / "config")
    return out


def resolve_config_path(path: Union[str, Path]) -> Path:
    """``path`` as given when it exists; a relative path not found from the current folder is
    looked up in the suite's config folder(s). Raises DriveConfigError naming the places tried."""
    p = Path(str(path)).expanduser()
    if p.is_file():
        return p
    tried = [str(p)]
    if not p.is_absolute():
        for folder in _suite_config_dirs():
            for cand in (folder / p, folder / p.name):
                if cand.is_file():
                    return cand
                tried.append(str(cand))
    raise DriveConfigError(f"no bridge config file {str(path)!r} (tried {', '.join(dict.fromkeys(tried))})")


def drive_grid_from_config(path: Union[str, Path]) -> DriveGrid:
    """The DriveGrid of the bridge config file ``path`` (see ``drive_grid_from_mapping``)."""
    p = resolve_config_path(path)
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise DriveConfigError(f"cannot read bridge config {p}: {exc}") from None
    try:
        return drive_grid_from_mapping(data, source=str(path))
    except DriveConfigError as exc:
        raise DriveConfigError(f"{path}: {exc}") from None


# --- the profile on the grid --------------------------------------------------------------------
def _cells_end(profile: CurrentProfile, period: float) -> int:
    """The last SYNC index at or before tf − coast."""
    return int(math.floor((profile.tf - profile.coast) / period + 1e-9))


def snap_times(profile: CurrentProfile, period: float) -> CurrentProfile:
    """``profile`` with every switch time on the nearest multiple of ``period`` (s), each step at
    least one period long and the last one ending at or before tf − coast; the currents kept.
    Raises PlanningError when the steps do not fit."""
    if period <= 0.0:
        return profile
    t = np.asarray(profile.step_times, dtype=float)
    n = t.shape[0] - 1
    last = _cells_end(profile, period)
    if last < n:
        raise PlanningError(f"{n} steps do not fit on a {period:g} s SYNC grid within tf - coast = "
                            f"{profile.tf - profile.coast:g} s; ask for fewer steps or a longer move")
    k = np.rint(t / period).astype(np.int64)
    k[0] = 0
    k[-1] = min(max(int(k[-1]), n), last)
    for j in range(1, n + 1):
        k[j] = max(k[j], k[j - 1] + 1)
    for j in range(n - 1, 0, -1):
        k[j] = min(k[j], k[j + 1] - 1)
    return dc_replace(profile, step_times=k.astype(float) * period, currents=profile.currents.copy())


def latched_times(profile: CurrentProfile, period: float,
                  tolerance: float = LATCH_TOLERANCE) -> CurrentProfile:
    """The profile a SYNC-latching drive applies when the motion starts at a SYNC: each switch at
    the first SYNC at or after its time (less ``tolerance`` periods); a step whose successor
    lands on the same SYNC is overwritten and vanishes. The bridge's rule for off-grid plans."""
    if period <= 0.0:
        return profile
    t = np.asarray(profile.step_times, dtype=float)
    k = np.ceil(t / period - tolerance).astype(np.int64)
    k[0] = 0
    keep = [j for j in range(len(k) - 1) if k[j + 1] > k[j]]
    times = np.r_[k[keep], k[-1]].astype(float) * period
    return dc_replace(profile, step_times=times, currents=profile.currents[keep].copy())


def on_quantum(profile: CurrentProfile, quantum: float) -> bool:
    """Are all currents of ``profile`` multiples of ``quantum`` (A)?"""
    c = np.asarray(profile.currents, dtype=float) / quantum
    return bool(np.all(np.abs(c - np.rint(c)) <= 1e-6))


def on_period(profile: CurrentProfile, period: float) -> bool:
    """Are all switch times of ``profile`` multiples of ``period`` (s), within 1 ns?"""
    if period <= 0.0:
        return True
    k = np.asarray(profile.step_times, dtype=float) / period
    return bool(np.all(np.abs(k - np.rint(k)) * period <= 1e-9))


# --- quantised currents, refined --------------------------------------------------------------
def refine_points(uncertain: Sequence[str], box: Optional[Mapping[str, float]]) -> np.ndarray:
    """The refinement's box points (scale factors (S, 3) of pv, pc, pt): nominal, corners and
    centre, the 3^k grid and REFINE_UNIFORM seeded uniform points (a seed other than the
    certificate's)."""
    unc = [u for u in FRICTION if u in uncertain]
    fr = box_fractions(unc, box)
    parts = [np.ones((1, 3))]
    if fr:
        parts += [box_corners(fr, FRICTION), box_grid(fr, FRICTION, 3),
                  box_uniform(fr, FRICTION, REFINE_UNIFORM, REFINE_SEED)]
    return np.ascontiguousarray(np.vstack(parts))


def worst_rest_error(params: Arm1DofParams, profile: CurrentProfile, q0: float, qf: float,
                     points: np.ndarray) -> float:
    """max |rest − qf| (rad) of ``profile`` over the box ``points`` (exact model; inf when the
    arm never stops at one of them)."""
    rest = track(params, profile, q0, points)[:, TR_REST]
    err = np.abs(rest - qf)
    return float(np.max(np.where(np.isfinite(err), err, math.inf)))


def refine_on_quantum(params: Arm1DofParams, profile: CurrentProfile, q0: float, qf: float,
                      uncertain: Sequence[str], box: Optional[Mapping[str, float]],
                      quantum: float, i_max: float,
                      max_evals: int = REFINE_MAX_EVALS) -> tuple[CurrentProfile, dict]:
    """Move the quantised currents of a 1-DOF ``profile`` by ±1 and ±2 quanta, one step at a
    time (the best move of each pass), while the worst rest error over ``refine_points`` falls;
    every current stays a multiple of ``quantum`` (A) within ±``i_max`` (A) and within
    REFINE_REACH quanta of its nearest rounding (a choice of rounding, not a new plan). Returns the
    profile and {worst before, worst after (rad), evaluations, quanta moved}."""
    points = refine_points(uncertain, box)
    base = np.rint(np.asarray(profile.currents[:, 0], dtype=float) / quantum).astype(np.int64)
    top = int(math.floor(i_max / quantum + 1e-9))

    def worst_of(k: np.ndarray) -> float:
        return worst_rest_error(params, dc_replace(profile, currents=(k * quantum).reshape(-1, 1)),
                                q0, qf, points)

    best_k, best = base.copy(), worst_of(base)
    before, evals = best, 1
    while evals < max_evals:
        cand_k, cand = best_k, best
        for j in range(best_k.shape[0]):
            for d in (-2, -1, 1, 2):
                k = best_k.copy()
                k[j] += d
                if abs(int(k[j])) > top or abs(int(k[j] - base[j])) > REFINE_REACH:
                    continue
                w = worst_of(k)
                evals += 1
                if w < cand:
                    cand_k, cand = k, w
        if cand >= best:
            break
        best_k, best = cand_k, cand
    out = dc_replace(profile, currents=(best_k * quantum).astype(float).reshape(-1, 1))
    return out, {"worst_before_rad": before, "worst_after_rad": best, "evaluations": evals,
                 "quanta_moved": int(np.sum(np.abs(best_k - base)))}


# --- the landing of a drive-exact profile, judged ---------------------------------------------
LANDING_MARGIN = 2.0      # times the first-order effect of the current changes (curvature, kinks)


def landing_allowance(params: Any, profile: CurrentProfile, q0: Sequence[float],
                      changes: np.ndarray, quantum: float, tol: float,
                      rest_error_before: Union[Sequence[float], np.ndarray]) -> np.ndarray:
    """How far (rad, per joint) the nominal rest of a drive-exact ``profile`` may lie from the
    goal: the planned profile's own rest error (``rest_error_before``, at least ``tol``) plus
    ``LANDING_MARGIN`` × Σ_k |∂rest_j/∂I_k|·|ΔI_k| — the first-order effect of the current
    changes the drive's quantum forced (``changes``, A, the profile's shape; ∂rest/∂I by central
    differences of ±quantum/2 on ``profile``). Moving switch times is not a current change:
    a landing moved by the SYNC grid is not allowed for here."""
    from ff_planner.model.simulate import rest_position   # the model layer's exact simulation

    cur = np.asarray(profile.currents, dtype=float)
    dq = np.abs(np.asarray(changes, dtype=float).reshape(cur.shape))
    h = 0.5 * float(quantum)
    spread = np.zeros(cur.shape[1])
    for idx in zip(*np.nonzero(dq > 0.0)):
        up, down = cur.copy(), cur.copy()
        up[idx] += h
        down[idx] -= h
        r_up = rest_position(params, dc_replace(profile, currents=up), q0)
        r_dn = rest_position(params, dc_replace(profile, currents=down), q0)
        spread += np.abs(r_up - r_dn) / (2.0 * h) * dq[idx]
    base = np.maximum(np.abs(np.asarray(rest_error_before, dtype=float)), float(tol))
    return base + float(tol) + LANDING_MARGIN * spread


LAND_NFEV = 200           # evaluations of the landing fix, at most


def land_on_times(params: Arm1DofParams, profile: CurrentProfile, q0: float, qf: float
                  ) -> Optional[CurrentProfile]:
    """The 1-DOF ``profile`` (switch times already on the drive's grid) with its currents moved
    as little as possible (least squares, |I| ≤ i_max) so that the nominal arm rests at ``qf``
    (rad) again: a plan whose switches moved to the SYNC grid (a time-optimal bang-bang switch,
    a coast end) lands elsewhere by the impulse of the shift. None when it finds no such
    currents (rest error above 1e-9 rad)."""
    from scipy.optimize import least_squares   # bounded Levenberg-Marquardt-type solver

    from ff_planner.model.simulate import rest_position

    x0 = np.asarray(profile.currents[:, 0], dtype=float)
    i_max = float(params.i_max)
    scale = max(1.0, float(np.max(np.abs(x0))))

    def residuals(x: np.ndarray) -> np.ndarray:
        prof = dc_replace(profile, currents=x.reshape(-1, 1))
        rest = float(rest_position(params, prof, [q0])[0])
        if not math.isfinite(rest):
            rest = 1e3
        return np.r_[1e3 * (rest - qf), 1e-3 * (x - x0) / scale]

    sol = least_squares(residuals, np.clip(x0, -i_max, i_max), bounds=(-i_max, i_max),
                        method="trf", x_scale=scale, max_nfev=LAND_NFEV)
    out = dc_replace(profile, currents=sol.x.reshape(-1, 1))
    err = abs(float(rest_position(params, out, [q0])[0]) - qf)
    return out if err <= 1e-9 * max(1.0, abs(qf)) or err <= 1e-7 else None

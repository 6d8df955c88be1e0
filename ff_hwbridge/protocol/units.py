"""Unit conversions between the suite (A, rad, rad/s, joint side) and an EPOS drive's objects.

ONE place for them. Drive-side units per maxon's EPOS4 Firmware Specification / object
dictionary. maxon's own pages were not reachable through the search tool here; what was found and
agrees: a public ROS EPOS driver (eposx_hardware) writes 0x3001:05 as torque constant [mNm/A] x 1000
(so µNm/A) and takes the CST rated torque as nominal current x torque constant; a public EtherCAT
EPOS4 driver reads 0x6076 and divides by 1000 to get mNm (so µNm); CiA 402 defines 0x6071/0x6077
in per mille of 0x6076. Re-check against the firmware spec of the drive in use:

- 0x3001:01 nominal current, UNSIGNED32, mA.
- 0x3001:02 output current limit, UNSIGNED32, mA.
- 0x3001:05 torque constant, UNSIGNED32, in 0.001 mNm/A (= µNm/A); e.g. 26.7 mNm/A -> 26700.
- 0x6076 motor rated torque, UNSIGNED32, in 0.001 mNm (= µNm). The EPOS4 derives it as
  nominal current x torque constant, so rated torque [µNm] = 0x3001:01 [mA] x 0x3001:05 [µNm/A] / 1000.
- 0x6071 target torque / 0x6077 torque actual, INTEGER16, per mille of 0x6076. Hence
  per mille = 1000 x kt x I / (kt x I_nominal) = 1000 x I / I_nominal: the torque constant cancels.
- 0x30D1:02 current actual value, INTEGER32, mA (EPOS4); 0x6078 current actual, INTEGER16, mA
  (EPOS2); 0x2030 current mode setting value, INTEGER16, mA (EPOS2).
- 0x6064 position actual value, INTEGER32, increments of the motor shaft encoder
  (counts_per_rev = 4 x encoder lines for a quadrature encoder).
- 0x606C velocity actual value, INTEGER32, motor rpm (the EPOS default velocity unit).

Joint angle = increments / counts_per_rev x 2 pi / gear_ratio; joint velocity = rpm x 2 pi / 60 /
gear_ratio. Currents are motor currents (A) on both sides; the joint torque is gear_ratio x kt x I.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

FAMILIES = ("epos4", "epos2")
INT16_MIN, INT16_MAX = -32768, 32767
TWO_PI = 2.0 * math.pi


class UnitsError(ValueError):
    """Drive or motor data that cannot define unit conversions; the message says what to change."""


def _positive(name: str, value: Any) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise UnitsError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v <= 0.0:
        raise UnitsError(f"{name} must be a finite number > 0, got {value!r}")
    return v


@dataclass(frozen=True)
class DriveUnits:
    """Conversions for one joint driven by one EPOS.

    family:              'epos4' (setpoint 0x6071 per mille of rated torque) or 'epos2'
                         (setpoint 0x2030 in mA).
    nominal_current:     A, motor nominal current (EPOS4 0x3001:01 / 1000); sets the per mille.
    torque_constant:     Nm/A, motor kt (EPOS4 0x3001:05 x 1e-6).
    counts_per_rev:      encoder increments per motor revolution (0x6064 units).
    gear_ratio:          motor revolutions per joint revolution (n).
    direction:           +1 or -1: joint sign relative to the motor's positive direction.
    """

    family: str = "epos4"
    nominal_current: float = 3.0
    torque_constant: float = 0.0267
    counts_per_rev: float = 2048.0
    gear_ratio: float = 54.0
    direction: int = 1

    def __post_init__(self) -> None:
        fam = str(self.family).lower()
        if fam not in FAMILIES:
            raise UnitsError(f"family must be one of {FAMILIES}, got {self.family!r}")
        object.__setattr__(self, "family", fam)
        for name in ("nominal_current", "torque_constant", "counts_per_rev", "gear_ratio"):
            object.__setattr__(self, name, _positive(name, getattr(self, name)))
        if self.direction not in (1, -1):
            raise UnitsError(f"direction must be 1 or -1, got {self.direction!r}")

    # --- construction ---------------------------------------------------------------------------
    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> "DriveUnits":
        """From a YAML mapping with the field names above (SI units); unknown keys are refused."""
        if not isinstance(data, Mapping):
            raise UnitsError(f"units must be a mapping, got {type(data).__name__}")
        known = {"family", "nominal_current", "torque_constant", "counts_per_rev", "gear_ratio",
                 "direction"}
        unknown = sorted(set(data) - known)
        if unknown:
            raise UnitsError(f"unknown units key(s) {unknown}; known: {sorted(known)}")
        return cls(**dict(data))

    @classmethod
    def from_drive_objects(cls, family: str, nominal_current_ma: int, torque_constant_unm_per_a: int,
                           counts_per_rev: float, gear_ratio: float, direction: int = 1) -> "DriveUnits":
        """From raw drive objects: nominal current (mA; EPOS4 0x3001:01, EPOS2 0x6410:01) and
        torque constant (µNm/A, EPOS4 0x3001:05; EPOS2 has none: pass the datasheet value)."""
        return cls(family=family, nominal_current=_positive("nominal_current_ma", nominal_current_ma) / 1000.0,
                   torque_constant=_positive("torque_constant", torque_constant_unm_per_a) * 1e-6,
                   counts_per_rev=counts_per_rev, gear_ratio=gear_ratio, direction=direction)

    # --- drive object values (what a drive reports / the simulator serves) ----------------------
    @property
    def nominal_current_ma(self) -> int:
        """0x3001:01 / 0x6410:01, mA."""
        return int(round(self.nominal_current * 1000.0))

    @property
    def torque_constant_raw(self) -> int:
        """0x3001:05, µNm/A."""
        return int(round(self.torque_constant * 1e6))

    @property
    def rated_torque_raw(self) -> int:
        """0x6076 motor rated torque, µNm (= kt x I_nominal)."""
        return int(round(self.torque_constant * self.nominal_current * 1e6))

    @property
    def rated_torque(self) -> float:
        """Nm, motor rated torque."""
        return self.torque_constant * self.nominal_current

    # --- current ------------------------------------------------------------------------------
    def amps_to_per_mille(self, amps: float) -> int:
        """Motor current (A) -> 0x6071 target torque (per mille of rated torque), saturated to INT16."""
        return _sat16(1000.0 * self.direction * float(amps) / self.nominal_current)

    def per_mille_to_amps(self, per_mille: float) -> float:
        """0x6071 / 0x6077 (per mille of rated torque) -> motor current (A)."""
        return self.direction * float(per_mille) * self.nominal_current / 1000.0

    def amps_to_ma(self, amps: float) -> int:
        """A -> mA (0x2030), saturated to INT16."""
        return _sat16(1000.0 * self.direction * float(amps))

    def ma_to_amps(self, ma: float) -> float:
        """mA (0x30D1:02, 0x6078, 0x2030) -> A."""
        return self.direction * float(ma) / 1000.0

    def amps_to_setpoint(self, amps: float, limit: float | None = None) -> int:
        """Motor current (A) -> the family's RPDO setpoint (EPOS4 per mille, EPOS2 mA).

        With ``limit`` (A) the raw value is also clamped to ``setpoint_limit(limit)``, so that
        rounding can never produce a setpoint above the limit.
        """
        raw = self.amps_to_per_mille(amps) if self.family == "epos4" else self.amps_to_ma(amps)
        if limit is not None:
            lim = self.setpoint_limit(limit)
            raw = max(-lim, min(lim, raw))
        return raw

    def setpoint_limit(self, limit: float) -> int:
        """The largest raw setpoint magnitude whose current is <= ``limit`` (A), rounded down."""
        lim = float(limit)
        if not math.isfinite(lim) or lim <= 0.0:
            return 0
        scale = 1000.0 / self.nominal_current if self.family == "epos4" else 1000.0
        raw = int(math.floor(lim * scale))
        while raw > 0 and abs(self.setpoint_to_amps(raw)) > lim:   # guard float rounding
            raw -= 1
        while raw < INT16_MAX and abs(self.setpoint_to_amps(raw + 1)) <= lim:
            raw += 1
        return min(raw, INT16_MAX)

    def setpoint_to_amps(self, raw: float) -> float:
        """The family's RPDO setpoint -> motor current (A)."""
        return self.per_mille_to_amps(raw) if self.family == "epos4" else self.ma_to_amps(raw)

    @property
    def current_resolution(self) -> float:
        """A, one step of the setpoint (EPOS4: I_nominal / 1000; EPOS2: 1 mA)."""
        return self.nominal_current / 1000.0 if self.family == "epos4" else 0.001

    def joint_torque(self, amps: float) -> float:
        """Nm at the joint for a motor current: gear_ratio x kt x I."""
        return self.gear_ratio * self.torque_constant * float(amps)

    # --- position / velocity ------------------------------------------------------------------
    def increments_to_rad(self, increments: float) -> float:
        """0x6064 (motor encoder increments) -> joint angle (rad)."""
        return self.direction * float(increments) / self.counts_per_rev * TWO_PI / self.gear_ratio

    def rad_to_increments(self, rad: float) -> int:
        """Joint angle (rad) -> motor encoder increments (rounded)."""
        return int(round(self.direction * float(rad) * self.gear_ratio / TWO_PI * self.counts_per_rev))

    def rpm_to_rad_s(self, rpm: float) -> float:
        """0x606C (motor rpm) -> joint velocity (rad/s)."""
        return self.direction * float(rpm) * TWO_PI / 60.0 / self.gear_ratio

    def rad_s_to_rpm(self, rad_s: float) -> int:
        """Joint velocity (rad/s) -> motor rpm (rounded, 0x606C units)."""
        return int(round(self.direction * float(rad_s) * self.gear_ratio * 60.0 / TWO_PI))


def _sat16(x: float) -> int:
    """Round to int and saturate to INT16; NaN -> 0."""
    if math.isnan(x):
        return 0
    if x >= INT16_MAX:
        return INT16_MAX
    if x <= INT16_MIN:
        return INT16_MIN
    return int(round(x))

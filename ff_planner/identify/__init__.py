"""Friction identification from the arm's own motions (no ROS).

``excitation`` designs constant-current runs inside a position/velocity envelope, ``records``
holds measured runs (``ff-identify-records/1`` files), ``fit`` fits Eq. 9 (pv, pc, pt; J
optionally) by output-error least squares on the exact simulator with 95 % intervals and model
adequacy tests, ``output`` writes the parameter file, the JSON summary and the report;
``measure`` simulates measured runs (encoder quantisation, current noise, optionally friction
that is not Eq. 9) for tests and benchmarks; ``learn`` updates the estimate from the measured rest
positions of executed motions (learning from use). Units: SI (rad, rad/s, A, s, Nm, Nm·s/rad; pt a fraction).
"""
from ff_planner.identify.excitation import Envelope, Excitation, ExcitationRun, design_excitation
from ff_planner.identify.fit import FitResult, fit_friction
from ff_planner.identify.records import RunRecord, load_records, save_records

__all__ = ["Envelope", "Excitation", "ExcitationRun", "FitResult", "RunRecord", "design_excitation",
           "fit_friction", "load_records", "save_records"]

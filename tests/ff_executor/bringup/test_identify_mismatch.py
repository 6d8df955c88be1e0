"""On-stack identification of an arm whose friction is not Eq. 9 (a Stribeck dip): the fit says
MODEL MISMATCH instead of claiming tight intervals. A module of its own: its stack must not share
the two cores with another module's stack (a starved simulated drive handles its frames late)."""
from __future__ import annotations

import math

import pytest

from ff_executor.bringup.identify import run_on_stack
from ff_planner.identify import Envelope, design_excitation, fit_friction
from ff_planner.model.params import preset

pytestmark = pytest.mark.integration

BASE = preset("table2")
#: all three off table 2: pv −15 %, pc +20 %, pt −15 %
TRUE = {"pv": -0.0425, "pc": 0.228, "pt": 0.187}
ENV = Envelope(-1.0, 1.0, 3.0, i_max=3.0)


def test_identification_with_friction_that_is_not_eq9_is_flagged_on_the_stack(tmp_path):
    ex = design_excitation(BASE, ENV, 0.0, levels=[0.75, 1.5, 3.0], timing_margin=0.02)
    records, meta = run_on_stack(ex, BASE, TRUE, 0.0, log=lambda s: None, run_dir=str(tmp_path),
                                 friction={"stribeck": 0.3, "stribeck_speed": 0.1})
    assert meta["friction_mismatch"]["stribeck"] == 0.3 and meta["timing"] == "bus"
    fit = fit_friction(records, BASE)
    assert not fit.adequate and "MODEL MISMATCH" in fit.message
    assert math.isfinite(fit.rms) and fit.rms > 3.0 * fit.sigma

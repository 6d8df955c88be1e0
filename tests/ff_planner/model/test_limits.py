"""MotionLimits validation and Excursion checks (rad, rad/s)."""
import math

import pytest

from ff_planner.core.errors import PlanningError
from ff_planner.model.limits import Excursion, MotionLimits
from ff_planner.model.profile import PlanRequest, RobustnessCertificate


def test_empty_limits_accept_anything():
    lim = MotionLimits.of()
    assert lim.empty
    lim.validate(1, [0.0], [1.0])


@pytest.mark.parametrize("kw, text", [
    (dict(position_min=[0.0, 0.0]), "one per joint"),
    (dict(velocity_max=[0.0]), "velocity_max must be > 0"),
    (dict(velocity_max=[math.nan]), "must be numbers"),
    (dict(position_min=[1.0], position_max=[0.5]), "must be below"),
    (dict(position_min=[0.2]), "start q0 = 0 rad is below position_min"),
    (dict(position_max=[0.9]), "goal qf = 1 rad is above position_max"),
])
def test_bad_limits_say_what_to_change(kw, text):
    with pytest.raises(PlanningError, match=text):
        MotionLimits.of(**kw).validate(1, [0.0], [1.0])


def test_request_validates_limits_and_tolerance():
    PlanRequest(limits=MotionLimits.of([-0.3], [1.05], [4.0]), tolerance=0.002,
                move_time_max=3.0).validate()
    with pytest.raises(PlanningError, match="position_max"):
        PlanRequest(limits=MotionLimits.of(position_max=[0.5])).validate()
    with pytest.raises(PlanningError, match="tolerance"):
        PlanRequest(tolerance=-1.0).validate()
    with pytest.raises(PlanningError, match="move_time_max"):
        PlanRequest(move_time_max=1e9).validate()


def test_excursion_violations_and_round_trip():
    ex = Excursion([-0.1], [1.02], [3.0], [-0.4], [1.1], [4.5])
    lim = MotionLimits.of([-0.3], [1.05], [4.0])
    v = ex.violations(lim)
    assert len(v) == 3 and "position_min" in v[0] and "position_max" in v[1] and "velocity_max" in v[2]
    assert ex.violations(MotionLimits.of([-1.0], [2.0], [10.0])) == []
    assert ex.violations(None) == []
    assert Excursion.from_dict(ex.to_dict()) == ex
    cert = RobustnessCertificate(box={"pv": 0.2}, worst_rest_error=1e-3, worst_at={}, per_parameter={},
                                 moving_at_tf=0.0, switch_timing=[], samples=1, excursion=ex)
    assert cert.to_dict()["excursion"]["worst_min"] == [-0.4]

"""ff-motion/1: exact keys, round trip, clear validation errors, independent re-simulation."""
from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from ff_planner.export.motion_file import (FORMAT, REQUIRED_KEYS, MotionFileError, motion_to_dict,
                                           read_motion, validate_motion_dict, verify_motion, write_motion)
from ff_planner.model.params import Arm1DofParams, Scara2Params
from ff_planner.model.profile import CurrentProfile, PlanRequest, PlanResult
from ff_planner.model.simulate import simulate
from ff_planner.optimize.baselines import plan_baseline


@pytest.fixture(scope="module")
def result() -> PlanResult:
    return plan_baseline(PlanRequest(objective="energy-optimal", steps=20))


def test_motion_file_has_the_required_keys(result, tmp_path):
    path = write_motion(tmp_path / "m.json", result)
    d = json.loads(path.read_text())
    assert set(REQUIRED_KEYS) <= set(d)
    assert d["format"] == FORMAT == "ff-motion/1" and d["model"] == "arm1dof"
    assert set(d["params"]) == set(Arm1DofParams.keys())
    assert d["params"]["pt"] == 0.22 and d["tf"] == 1.0 and d["coast"] == 0.05
    assert len(d["step_times"]) == len(d["currents"]) + 1 == 21
    assert d["step_times"][0] == 0.0 and d["step_times"][-1] == pytest.approx(0.95)
    assert all(len(row) == 1 for row in d["currents"])
    assert set(d["predicted"]) >= {"q_final", "qd_final", "sensitivities"}
    assert set(d["predicted"]["sensitivities"]) == {"pv", "pc", "pt"}


def test_round_trip(result, tmp_path):
    m = read_motion(write_motion(tmp_path / "m.json", result))
    assert m.params == result.params
    np.testing.assert_array_equal(m.profile.currents, result.profile.currents)
    np.testing.assert_array_equal(m.profile.step_times, result.profile.step_times)
    assert m.uncertain == ["pv", "pc", "pt"] and m.tf == 1.0 and m.coast == 0.05
    assert m.predicted_sensitivities == pytest.approx(result.sensitivities)
    assert m.extra["objective"] == "energy-optimal"


@pytest.mark.parametrize("mutate, needle", [
    (lambda d: d.pop("currents"), "missing key"),
    (lambda d: d.update(format="ff-motion/2"), "format"),
    (lambda d: d.update(model="arm3dof"), "unknown model"),
    (lambda d: d["params"].pop("J"), "lacks ['J']"),
    (lambda d: d["params"].update(pc=-1.0), "pc"),
    (lambda d: d["params"].update(bogus=1.0), "unknown parameter"),
    (lambda d: d.update(q0=[0.0, 1.0]), "'q0' needs 1"),
    (lambda d: d.update(qf=[float("nan")]), "finite"),
    (lambda d: d["step_times"].pop(), "N+1"),
    (lambda d: d["currents"].__setitem__(0, [99.0]), "exceed the limit"),
    (lambda d: d["currents"].__setitem__(0, [1.0, 2.0]), "row 0"),
    (lambda d: d.update(tf=0.05), "tf > coast"),
    (lambda d: d.update(uncertain=["pq"]), "unknown parameter"),
    (lambda d: d["predicted"]["sensitivities"].update({"px": 1.0}), "px"),
    (lambda d: d["step_times"].__setitem__(2, 0.0), "increase"),
])
def test_validation_errors_are_clear(result, mutate, needle):
    d = motion_to_dict(result)
    bad = copy.deepcopy(d)
    mutate(bad)
    with pytest.raises(MotionFileError) as ei:
        validate_motion_dict(bad)
    assert needle in str(ei.value)


def test_read_errors(tmp_path):
    with pytest.raises(MotionFileError, match="cannot read"):
        read_motion(tmp_path / "absent.json")
    (tmp_path / "x.json").write_text("{not json")
    with pytest.raises(MotionFileError, match="not valid JSON"):
        read_motion(tmp_path / "x.json")
    (tmp_path / "y.json").write_text("[1, 2]")
    with pytest.raises(MotionFileError, match="JSON object"):
        read_motion(tmp_path / "y.json")


def test_verify_motion_resimulates_independently(result, tmp_path):
    path = write_motion(tmp_path / "m.json", result)
    nominal = verify_motion(path)
    assert nominal.prediction_mismatch < 1e-12 and nominal.max_error < 1e-8
    # central sensitivities recomputed from the file agree with the prediction it carries
    for k, v in result.sensitivities.items():
        assert nominal.sensitivities[k] == pytest.approx(v, rel=1e-4, abs=1e-6)
    pert = verify_motion(path, {"pc": 1.1, "pv": 0.9})
    assert pert.scale == {"pc": 1.1, "pv": 0.9}
    # an energy-optimal move is not robust: +10 % Coulomb friction visibly shortens it
    assert pert.error[0] < -1e-3 and pert.rest_error[0] < -1e-3
    # the check really uses the scaled parameters
    p = result.params.replace(pc=result.params.pc * 1.1, pv=result.params.pv * 0.9)
    assert pert.q_final[0] == pytest.approx(simulate(p, result.profile, [0.0]).q_f[0], abs=1e-12)
    with pytest.raises(MotionFileError, match="unknown parameter"):
        verify_motion(path, {"foo": 1.1})


def test_scara2_motion_round_trip(tmp_path):
    p = Scara2Params()
    prof = CurrentProfile.uniform([[1.0, 0.5], [-1.0, -0.5]], 0.5)
    res = PlanResult(success=False, message="hand-made", profile=prof, model="scara2", params=p,
                     q0=np.array([-0.5, 0.0]), qf=np.array([0.5, 0.0]), uncertain=["pc1", "pc2"],
                     objective="robust-derivative", q_final=np.zeros(2), qd_final=np.zeros(2),
                     sensitivities={"q1/pc1": 0.1, "q2/pc2": 0.2})
    m = read_motion(write_motion(tmp_path / "s.json", res))
    assert m.model == "scara2" and m.profile.currents.shape == (2, 2)
    assert set(json.loads((tmp_path / "s.json").read_text())["params"]) == set(Scara2Params.keys())
    chk = verify_motion(m, {"pc2": 1.2}, sensitivities=False)
    assert chk.q_final.shape == (2,) and np.all(np.isfinite(chk.rest_position))


def test_robust_plan_file_stays_robust_when_resimulated_perturbed(tmp_path, robust_plan_1dof):
    """The k = 3 robust plan, written and re-simulated from the file with perturbed friction,
    keeps zero first derivatives (errors second order in the change)."""
    res = robust_plan_1dof
    assert res.robust
    path = write_motion(tmp_path / "k3.json", res)
    nom = verify_motion(path)
    assert nom.max_error <= 1e-6 and nom.qd_final[0] == 0.0 and nom.prediction_mismatch < 1e-12
    assert all(abs(v) <= 1e-6 for v in nom.sensitivities.values())
    for name in ("pv", "pc", "pt"):
        for s in (0.999, 1.001):
            chk = verify_motion(path, {name: s}, sensitivities=False)
            # first-order robust: a 0.1 % change costs at most ~curvature * dp^2 (<< 0.1 % of a
            # non-robust plan's ~3e-3 rad per 0.1 %)
            assert chk.max_error <= 2e-5, (name, s, chk.error)


def test_certificate_round_trips_through_the_motion_file(tmp_path):
    from ff_planner.export.motion_file import read_motion, write_motion
    from ff_planner.optimize.planner import plan

    r = plan(PlanRequest(objective="energy-optimal"))
    path = write_motion(tmp_path / "m.json", r)
    cert = json.loads(path.read_text())["certificate"]
    assert cert["worst_rest_error"] == pytest.approx(r.certificate.worst_rest_error)
    assert cert["worst_at"] == r.certificate.worst_at
    assert cert["units"]["worst_rest_error"] == "rad"
    assert read_motion(path).extra["certificate"]["box"] == {"pv": 0.2, "pc": 0.2, "pt": 0.2}

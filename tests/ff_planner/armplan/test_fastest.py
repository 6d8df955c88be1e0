"""Tolerance first for arms from a URDF (ff_planner.armplan.fastest): the same search as the 1-DOF
planner's, run on the n-joint planner. On the paper's 1-DOF arm as a URDF the n-joint planner's plan
at N = 6 is the 1-DOF robust-derivative plan with the same certificate, so both searches must find
the same move time; an unreachable tolerance answers the least-worst plan, labelled."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from ff_planner.arm.model import load_arm
from ff_planner.armplan.fastest import plan_fastest_arm
from ff_planner.cli import plan_urdf
from ff_planner.core.errors import PlanningError
from ff_planner.model.profile import PlanRequest
from ff_planner.optimize.fastest import SearchSettings, plan_fastest

ARMS = Path(__file__).resolve().parents[3] / "config" / "arms"
# few trials (each n-joint plan of this arm costs 2-8 s): no second seed, the knee where the
# first seed meets the tolerance
QUICK = SearchSettings(retries=0, hopeless_factor=1.0)


@pytest.fixture(scope="module")
def arm1():
    return load_arm(ARMS / "arm1dof.cell.yaml", ARMS / "arm1dof.urdf")


def test_the_n_joint_search_finds_the_1dof_searchs_move_time(arm1):
    tol, tf_max = 0.15, 1.8      # rad, s: measured, N = 6: 230 mrad at 1.50 s, 129 at 1.55 s
    one = plan_fastest(PlanRequest(objective="robust-derivative", q0=(0.0,), qf=(1.0,), steps=6,
                                   coast=0.05, tolerance=tol, move_time_max=tf_max,
                                   time_budget=60.0), settings=QUICK)
    # the n-joint search over [1.40, 1.65] s only (its plans are ~100x the 1-DOF planner's cost)
    arm = plan_fastest_arm(arm1, [0.0], [1.0], tol, tf_max=1.65, tf_min=1.40, coast=0.05, steps=6,
                           time_budget=400.0, settings=QUICK)   # a cap: 20 s wall at load 3
    r = arm.result
    # the same planner and certificate: equal certified worst at every tf both searches tried
    w1 = {round(t["tf"], 6): t["worst_rest_error"] for t in one.extra["tolerance_search"]["trials"]}
    both = [(w1[round(t["tf"], 6)], t["worst_rest_error"])
            for t in r.extra["tolerance_search"]["trials"] if round(t["tf"], 6) in w1]
    assert both and all(a == pytest.approx(b, rel=1e-6) for a, b in both), both
    assert one.success and r.success and r.error_code == "OK"
    assert r.extra["tolerance_search"]["complete"] and r.extra["tolerance_search"]["met"]
    tf1, tfa = float(one.profile.tf), float(r.profile.tf)
    assert abs(tfa - tf1) <= 0.05 * tf1, (tf1, tfa)
    assert r.certificate is not None and r.certificate.worst_rest_error <= tol
    assert arm.plan.certificate is r.certificate and float(arm.plan.profile.tf) == tfa
    # the bracket: the tf just below the answer was tried and failed
    below = [t for t in r.extra["tolerance_search"]["trials"] if t["tf"] < tfa]
    assert below and not any(t["meets"] for t in below)
    assert max(t["tf"] for t in below) >= 0.98 * tfa


def test_an_unreachable_tolerance_answers_the_least_worst_plan_labelled(arm1):
    arm = plan_fastest_arm(arm1, [0.0], [1.0], 1e-4, tf_max=1.0, coast=0.05, steps=6,
                           time_budget=30.0, settings=QUICK)
    r = arm.result
    assert not r.success and r.best_effort and r.error_code == "NO_ROBUST_PLAN"
    assert "no move time up to 1 s is certified within 0.1 mrad" in r.message
    assert "relax the tolerance" in r.message
    worsts = [t["worst_rest_error"] for t in r.extra["tolerance_search"]["trials"]]
    assert r.certificate is not None and r.certificate.worst_rest_error == min(worsts) > 1e-4


def test_bad_requests_are_refused_before_planning(arm1):
    for kwargs, text in ((dict(tolerance=-1.0), "tolerance must be"),
                         (dict(tolerance=float("nan")), "tolerance must be"),
                         (dict(tolerance=0.1, tf_max=0.05), "longest move time"),
                         (dict(tolerance=0.1, time_budget=0.0), "time_budget"),
                         (dict(tolerance=0.1, tf_min=4.0), "shortest move time"),
                         (dict(tolerance=0.1, qf=[1.0, 2.0]), "q0 and qf need 1")):
        args = dict(dict(qf=[1.0]), **kwargs)
        with pytest.raises(PlanningError, match=text):
            plan_fastest_arm(arm1, [0.0], args.pop("qf"), args.pop("tolerance"), **args)


def test_ff_plan_urdf_tolerance(tmp_path, capsys):
    base = ["--urdf", str(ARMS / "arm1dof.urdf"), "--cell", str(ARMS / "arm1dof.cell.yaml"),
            "--q0", "0", "--qf", "1", "--steps", "6"]
    with pytest.raises(SystemExit) as info:
        plan_urdf.main(base + ["--tolerance", "0.01", "--tf", "1"])
    assert info.value.code == 2 and "not both" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        plan_urdf.main(base + ["--tf-max", "2"])
    assert "give --tolerance too" in capsys.readouterr().err
    out = tmp_path / "plan.json"
    code = plan_urdf.main(base + ["--tolerance", "1e-4", "--tf-max", "1", "--time-budget", "20",
                                  "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 1 and "no move time up to 1 s is certified within 0.1 mrad" in err
    assert "BEST-EFFORT (tolerance not met)" in err
    d = json.loads(out.read_text())
    assert d["tolerance_search"]["met"] is False and d["tolerance_search"]["trials"]
    assert d["certificate"]["worst_rest_error"] > 1e-4 and d["tf"] <= 1.0


def test_a_registered_arm_request_with_a_tolerance():
    from ff_planner.armplan.requests import ArmRequest, plan_registered, registry_from_parameters

    reg = registry_from_parameters({"arms.arm1dof.urdf": str(ARMS / "arm1dof.urdf"),
                                    "arms.arm1dof.cell": str(ARMS / "arm1dof.cell.yaml")}, Path)
    limits = dict(default_time_budget=10.0, max_time_budget=60.0, max_steps=40,
                  max_move_time=60.0, coast=0.05)
    r = plan_registered(ArmRequest("urdf:arm1dof", [0.0], [1.0], 0.0, steps=6, tolerance=1e-4,
                                   move_time_max=1.0), reg, **limits)
    assert not r.success and r.error_code == "NO_ROBUST_PLAN" and r.best_effort
    assert r.message.startswith("no move time up to 1 s is certified within 0.1 mrad")
    assert r.extra["tolerance_search"]["trials"] and r.model == "urdf:arm1dof"
    for req, text in ((ArmRequest("urdf:arm1dof", [0.0], [1.0], 1.0, move_time_max=2.0),
                       "give a tolerance too"),
                      (ArmRequest("urdf:arm1dof", [0.0], [1.0], 0.0, tolerance=0.1,
                                  move_time_max=61.0), "move_time_max must be"),
                      (ArmRequest("urdf:arm1dof", [0.0], [1.0], 0.0, tolerance=-1.0),
                       "tolerance must be")):
        bad = plan_registered(req, reg, **limits)
        assert not bad.success and bad.error_code == "INVALID_REQUEST" and text in bad.message

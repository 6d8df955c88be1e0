"""PlannerService: limits and a tolerance through the request fields, the node's cell limits."""
from __future__ import annotations

import math

import pytest

from ff_planner.model.limits import MotionLimits
from ff_planner.optimize.fastest import DEFAULT_MOVE_TIME_MAX
from ff_planner.service.planner_service import (PlannerService, RequestFields, ServiceConfig,
                                                ServiceConfigError, config_from_mapping)

ROBUST = dict(model="arm1dof", q0=[0.0], qf=[1.0], move_time=1.0, uncertain=["pv", "pc", "pt"])


@pytest.fixture(scope="module")
def idle_service():
    svc = PlannerService(ServiceConfig())
    yield svc
    svc.close()


def test_limits_and_tolerance_reach_the_plan_request(idle_service):
    req = idle_service.make_request(RequestFields(**dict(
        ROBUST, position_min=[-0.3], position_max=[1.05], velocity_max=[4.0]))).request
    assert req.limits == MotionLimits.of([-0.3], [1.05], [4.0]) and req.tolerance is None
    assert idle_service.make_request(RequestFields(**ROBUST)).request.limits is None
    tol = idle_service.make_request(RequestFields(**dict(ROBUST, move_time=0.0, tolerance=2e-3))).request
    assert tol.tolerance == 2e-3 and tol.move_time_max == DEFAULT_MOVE_TIME_MAX
    assert tol.tf == DEFAULT_MOVE_TIME_MAX          # checked (reach, grid) at the longest tf
    tol2 = idle_service.make_request(RequestFields(**dict(ROBUST, tolerance=2e-3, move_time_max=2.0)))
    assert tol2.request.move_time_max == 2.0 and tol2.request.tf == 2.0


BAD = [
    (dict(ROBUST, position_min=[0.5]), "below position_min"),
    (dict(ROBUST, position_max=[0.5]), "above position_max"),
    (dict(ROBUST, position_min=[0.0, 0.0]), "one per joint"),
    (dict(ROBUST, velocity_max=[0.0]), "velocity_max must be > 0"),
    (dict(ROBUST, position_min=[1.0], position_max=[-1.0]), "must be below"),
    (dict(ROBUST, tolerance=-1e-3), "tolerance must be"),
    (dict(ROBUST, tolerance=math.nan), "tolerance must be"),
    (dict(ROBUST, tolerance=1e-3, move_time_max=100.0), "move_time_max 100.0 s exceeds"),
    (dict(ROBUST, tolerance=1e-3, move_time_max=-1.0), "move_time_max must be"),
    (dict(ROBUST, q0=[1e308], qf=[1e308]), "beyond ±10000 rad"),
    (dict(ROBUST, override_names=["pt"], override_values=[1.5]), "pt must be < 1"),
    (dict(ROBUST, override_names=["pc"], override_values=[1e-300]), "never comes to rest"),
]


@pytest.mark.parametrize("fields, text", BAD, ids=[t for _, t in BAD])
def test_bad_limits_or_tolerance_are_refused_at_once(idle_service, fields, text):
    res = idle_service.handle_fields(RequestFields(**fields))
    assert not res.success and res.error_code == "INVALID_REQUEST", (res.error_code, res.message)
    assert text in res.message and res.profile is None and res.extra["source"] == "invalid"


def test_cell_limits_from_the_configuration_fill_empty_request_fields():
    cfg = config_from_mapping({"arm1dof.position_min": [-0.3], "arm1dof.velocity_max": [4.0],
                               "workers": 1})
    assert cfg.limits["arm1dof"] == MotionLimits.of([-0.3], None, [4.0])
    svc = PlannerService(cfg)
    try:
        req = svc.make_request(RequestFields(**ROBUST)).request
        assert req.limits == MotionLimits.of([-0.3], None, [4.0])
        own = svc.make_request(RequestFields(**dict(ROBUST, velocity_max=[8.0]))).request
        assert own.limits == MotionLimits.of([-0.3], None, [8.0])     # the request's own wins
        two = svc.make_request(RequestFields(model="scara2", q0=[-0.5, 0.0], qf=[0.5, 0.0],
                                             move_time=1.0, uncertain=["pc1"])).request
        assert two.limits is None                                     # other model: none
    finally:
        svc.close()
    with pytest.raises(ServiceConfigError, match="one per joint"):
        config_from_mapping({"arm1dof.position_min": [-0.3, 0.0]})
    with pytest.raises(ServiceConfigError, match="must be numbers"):
        config_from_mapping({"arm1dof.velocity_max": ["fast"]})


@pytest.mark.integration
def test_a_tolerance_request_is_searched_in_a_worker(tmp_path):
    """The energy-optimal baseline (deterministic, fast) through the worker pool: the answer is
    the fastest tf certified within the tolerance, with every tf tried."""
    svc = PlannerService(ServiceConfig(workers=1, warmup=False, library_path=str(tmp_path / "l.sqlite")))
    svc.start()
    try:
        res = svc.handle_fields(RequestFields(**dict(ROBUST, objective="energy-optimal",
                                                     tolerance=0.7, move_time_max=1.5,
                                                     time_budget=60.0)))
        assert res.success, res.message
        info = res.extra["tolerance_search"]
        assert info["met"] and res.certificate.worst_rest_error <= 0.7
        assert res.profile.tf == min(t["tf"] for t in info["trials"] if t["meets"])
        assert res.profile.tf < 1.5 and len(info["trials"]) >= 3
        stats = svc.library.stats() if svc.library is not None else {}
        assert stats and sum(v for k, v in stats.items() if k != "param_sets") == 0   # not stored
    finally:
        svc.close()


@pytest.mark.integration
def test_a_request_with_limits_is_not_answered_from_the_library(tmp_path):
    """The library's task key holds no limits: such requests are planned, and not stored."""
    from tests.support.stand_in_planners import stub_plan

    svc = PlannerService(ServiceConfig(workers=1, warmup=False,
                                       library_path=str(tmp_path / "l.sqlite")), plan_fn=stub_plan)
    svc.start()
    try:
        first = svc.handle_fields(RequestFields(**ROBUST))
        assert first.extra["source"] == "cold"
        assert svc.handle_fields(RequestFields(**ROBUST)).extra["source"] in ("hit", "warm")
        limited = svc.handle_fields(RequestFields(**dict(ROBUST, velocity_max=[4.0])))
        assert limited.extra["source"] == "cold"
        assert svc.handle_fields(RequestFields(**dict(ROBUST, velocity_max=[4.0]))).extra["source"] == "cold"
    finally:
        svc.close()

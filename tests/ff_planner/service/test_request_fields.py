"""PlannerService: the request fields beyond the facade's (box, coast_max, switch_grid), the
predicted rest position, library rows that fit a request, progress and cancel."""
from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest

from ff_planner.library.store import MotionLibrary, record_from_result
from ff_planner.model.profile import CurrentProfile, PlanRequest, RobustnessCertificate
from ff_planner.model.simulate import rest_position
from ff_planner.library.gridded import GridPlanRequest, on_grid
from ff_planner.service.planner_service import (CANCELED, PlannerService, RequestFields,
                                                ServiceConfig, ServiceConfigError, _certificate_from_dict,
                                                _fits, config_from_mapping, predicted_rest)
from tests.support.stand_in_planners import stub_plan

ROBUST = dict(model="arm1dof", q0=[0.0], qf=[1.0], move_time=1.0, uncertain=["pv", "pc", "pt"])


@pytest.fixture(scope="module")
def idle_service():
    svc = PlannerService(ServiceConfig())
    yield svc
    svc.close()


BAD = [
    (dict(ROBUST, box_names=["pc"], box_fractions=[]), "1 box names but 0"),
    (dict(ROBUST, box_names=["pc", "pc"], box_fractions=[0.1, 0.2]), "repeat"),
    (dict(ROBUST, uncertain=["pc"], box_names=["pv"], box_fractions=[0.1]), "not uncertain"),
    (dict(ROBUST, box_names=["pc"], box_fractions=[1.0]), "in (0, 1)"),
    (dict(ROBUST, box_names=["pc"], box_fractions=[0.0]), "in (0, 1)"),
    (dict(ROBUST, box_names=["pc"], box_fractions=[math.nan]), "in (0, 1)"),
    (dict(ROBUST, coast_max=-0.1), "coast_max"),
    (dict(ROBUST, coast_max=math.inf), "coast_max"),
    (dict(ROBUST, objective="robust-box", coast_max=2.0), "coast_max < tf"),
    (dict(ROBUST, switch_grid=math.nan), "switch_grid"),
    (dict(ROBUST, switch_grid=2.0), "shorter than the move time"),
    (dict(ROBUST, steps=30, switch_grid=0.1), "do not fit"),
]


@pytest.mark.parametrize("fields, text", BAD, ids=[t for _, t in BAD])
def test_bad_new_fields_are_refused_at_once_with_what_to_change(idle_service, fields, text):
    before = idle_service.stats().get("requests", 0)
    res = idle_service.handle_fields(RequestFields(**fields))
    assert not res.success and res.error_code == "INVALID_REQUEST", (res.error_code, res.message)
    assert text in res.message and res.extra["source"] == "invalid"
    assert res.profile is None
    assert idle_service.stats()["requests"] == before + 1


def test_box_coast_max_and_grid_reach_the_plan_request(idle_service):
    req = idle_service.make_request(RequestFields(**dict(
        ROBUST, objective="robust-box", box_names=["pc"], box_fractions=[0.3], coast_max=0.2))).request
    assert req.box == {"pc": 0.3} and req.coast_max == 0.2
    assert isinstance(req, GridPlanRequest) and req.grid == 0.001
    plain = idle_service.make_request(RequestFields(**ROBUST)).request
    assert isinstance(plain, GridPlanRequest) and plain.grid == 0.001     # the node default
    assert plain.box is None and plain.coast_max == PlanRequest().coast_max
    mine = idle_service.make_request(RequestFields(**dict(ROBUST, switch_grid=0.002))).request
    assert mine.grid == 0.002
    none = idle_service.make_request(RequestFields(**dict(ROBUST, switch_grid=-1.0))).request
    assert getattr(none, "grid", None) is None
    base = idle_service.make_request(RequestFields(**dict(ROBUST, objective="time-optimal"))).request
    assert getattr(base, "grid", None) is None
    off = PlannerService(config_from_mapping({"switch_grid": 0.0}))
    try:
        assert getattr(off.make_request(RequestFields(**ROBUST)).request, "grid", None) is None
    finally:
        off.close()
    with pytest.raises(ServiceConfigError, match="switch_grid"):
        config_from_mapping({"switch_grid": -0.001})


def test_the_grid_request_puts_the_robust_plan_on_the_grid(idle_service):
    from ff_planner.optimize.planner import plan

    checked = idle_service.make_request(RequestFields(**dict(ROBUST, steps=7, starts=100, seed=2)))
    res = plan(checked)
    assert res.success and res.robust, res.message
    assert on_grid(res.profile, 0.001)
    ms = np.round(res.profile.step_times * 1e3, 6)
    assert len(set(np.diff(ms))) > 1            # 950 ms / 7 steps: not all equal on a 1 ms grid
    assert not on_grid(CurrentProfile.uniform(np.ones((7, 1)), 1.0, 0.05), 0.001)
    rest = predicted_rest(res, checked.params)
    expect = rest_position(checked.params, res.profile, [0.0])
    assert rest == pytest.approx([float(expect[0])], abs=1e-9) and abs(rest[0] - 1.0) < 1e-5


def test_predicted_rest_of_a_2dof_plan_is_q_final_when_at_rest():
    res = stub_plan(PlanRequest(model="scara2", q0=[0.0, 0.0], qf=[0.5, 0.2], uncertain=["pc1"]))
    assert predicted_rest(res) == [0.5, 0.2]
    res.qd_final = np.array([0.0, 0.3])       # still moving at tf, no rest position known
    assert predicted_rest(res) == []
    res.profile = None
    assert predicted_rest(res) == []


CERT = RobustnessCertificate(box={"pc": 0.2, "pv": 0.1}, worst_rest_error=2e-3, worst_at={"pc": 1.2, "pv": 0.9},
                             per_parameter={"pc": 1e-3, "pv": 5e-4}, moving_at_tf=0.25,
                             switch_timing=[1e-4, -2e-4], samples=300)


def test_certificate_round_trips_through_the_motion_dict():
    back = _certificate_from_dict(CERT.to_dict())
    assert back == CERT
    assert _certificate_from_dict({"box": {}}) is None


def test_library_rows_answer_only_requests_they_fit(tmp_path):
    grid_req = GridPlanRequest(grid=0.001, **ROBUST_REQ)
    with MotionLibrary(tmp_path / "lib.sqlite") as lib:
        off = stub_plan(PlanRequest(**ROBUST_REQ))
        off.profile = CurrentProfile(np.array([0.0, 0.1005, 0.5, 0.95]), np.ones((3, 1)), 1.0, 0.05)
        rec = record_from_result(PlanRequest(**ROBUST_REQ), off)
        assert not _fits(rec, grid_req)
        assert _fits(rec, PlanRequest(**ROBUST_REQ))             # no certificate, no box asked
        assert not _fits(rec, PlanRequest(**dict(ROBUST_REQ, box={"pc": 0.2})))
        off.certificate = RobustnessCertificate(box={"pc": 0.2}, worst_rest_error=0.0, worst_at={"pc": 1.0},
                                                per_parameter={"pc": 0.0}, moving_at_tf=0.0,
                                                switch_timing=[0.0] * 3, samples=1)
        rec = record_from_result(PlanRequest(**ROBUST_REQ), off)
        assert _fits(rec, PlanRequest(**ROBUST_REQ)) and not _fits(rec, grid_req)
        box_req = PlanRequest(**dict(ROBUST_REQ, objective="robust-box", box={"pc": 0.3}))
        boxed = stub_plan(box_req)
        boxed.certificate = RobustnessCertificate(box={"pc": 0.3}, worst_rest_error=0.0, worst_at={"pc": 1.0},
                                                  per_parameter={"pc": 0.0}, moving_at_tf=0.0,
                                                  switch_timing=[0.0] * 4, samples=1)
        brec = record_from_result(box_req, boxed)
        assert _fits(brec, box_req)
        assert not _fits(brec, PlanRequest(**dict(ROBUST_REQ, objective="robust-box", box={"pc": 0.2})))
        assert not _fits(brec, PlanRequest(**dict(ROBUST_REQ, objective="robust-box")))    # default ±20 %
        assert not _fits(brec, PlanRequest(**dict(ROBUST_REQ, objective="robust-box", box={"pc": 0.3},
                                                  coast_max=0.01, coast=0.0)))
        assert lib.put(brec)


ROBUST_REQ = dict(model="arm1dof", q0=[0.0], qf=[1.0], tf=1.0, uncertain=["pc"], starts=10)


@pytest.mark.integration
def test_progress_is_reported_and_cancel_stops_the_worker(tmp_path):
    from tests.ff_planner.service.stand_ins import progress_plan

    svc = PlannerService(ServiceConfig(workers=2, warmup=False, default_time_budget=60.0), plan_fn=progress_plan)
    svc.start()
    try:
        seen: list[dict] = []
        cancel = threading.Event()
        got: list = []
        fields = RequestFields(model="arm1dof", q0=[0.0], qf=[1.0], move_time=1.0, uncertain=["pc"],
                               seed=5, time_budget=60.0)
        t = threading.Thread(target=lambda: got.append(svc.handle_fields(fields, seen.append, cancel)))
        t.start()
        end = time.monotonic() + 30
        while time.monotonic() < end and not any("starts_done" in r for r in seen):
            time.sleep(0.05)
        assert any(r.get("starts_done", 0) >= 1 for r in seen), seen
        assert seen[0]["stage"] == "multistart" and seen[-1]["stage"] == "stand-in"
        t_cancel = time.monotonic()
        cancel.set()
        t.join(10)
        assert not t.is_alive() and time.monotonic() - t_cancel < 2.0
        res = got[0]
        assert not res.success and res.extra[CANCELED] and res.extra["source"] == "canceled"
        assert "canceled" in res.message and svc.stats()["canceled"] == 1
        # the pool serves on (the killed worker replaced)
        ok = svc.handle_fields(RequestFields(**dict(ROBUST, uncertain=["pc"], seed=1, starts=3)))
        assert ok.success, ok.message
    finally:
        svc.close()


def test_the_energy_optimal_baseline_gets_steps_whose_switches_are_on_the_grid(idle_service):
    for grid, want in ((0.01, 95), (0.001, 95), (-1.0, None)):     # tf - coast = 0.95 s
        req = idle_service.make_request(RequestFields(**dict(ROBUST, objective="energy-optimal",
                                                             switch_grid=grid))).request
        assert req.steps == want, (grid, req.steps)
    from ff_planner.optimize.planner import plan

    res = plan(idle_service.make_request(RequestFields(**dict(ROBUST, objective="energy-optimal",
                                                              switch_grid=0.01))).request)
    assert res.success and res.profile.n_steps == 95 and on_grid(res.profile, 0.01)

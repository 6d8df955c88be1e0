"""PlannerService, the planner node's logic without ROS: configuration, request validation, the
motion library's hits, shifts and warm starts, worker processes (pebble)."""
from __future__ import annotations

import numpy as np
import pytest

from ff_planner.library.gridded import on_grid
from ff_planner.library.store import MotionLibrary, record_from_result
from ff_planner.model.profile import BOX_DEFAULT_STEPS
from ff_planner.service.planner_service import (PlannerService, RequestFields, ServiceConfig,
                                                ServiceConfigError, config_from_mapping)
from tests.support.stand_in_planners import stub_plan


def test_service_config_refuses_unknown_names():
    cfg = config_from_mapping({"workers": 3, "arm1dof.params.pc": 0.25, "scara2.preset": "table3"})
    assert cfg.workers == 3 and cfg.model_params("arm1dof").pc == 0.25
    with pytest.raises(ServiceConfigError, match="unknown model parameter"):
        config_from_mapping({"arm1dof.params.friction": 1.0})
    with pytest.raises(ServiceConfigError, match="unknown planner parameter"):
        config_from_mapping({"wokers": 3})
    with pytest.raises(ServiceConfigError, match="preset"):
        config_from_mapping({"arm1dof.preset": "table3"})
    with pytest.raises(ServiceConfigError, match=">= 1"):
        config_from_mapping({"workers": 0})


def test_default_objective_and_current_quantum_parameters(tmp_path):
    cfg = config_from_mapping({"current_quantum": 0.003, "default_objective": "robust-derivative",
                               "library_path": ""})
    svc = PlannerService(cfg)
    req = svc.make_request(RequestFields(model="arm1dof", q0=[0.0], qf=[1.0], move_time=1.0)).request
    assert req.current_quantum == 0.003 and req.objective == "robust-derivative"
    asked = svc.make_request(RequestFields(model="arm1dof", q0=[0.0], qf=[1.0], move_time=1.0,
                                           objective="robust-box")).request
    assert asked.objective == "robust-box"
    with pytest.raises(ServiceConfigError, match="current_quantum"):
        config_from_mapping({"current_quantum": -0.001})
    with pytest.raises(ServiceConfigError, match="default_objective"):
        config_from_mapping({"default_objective": "fastest"})


def test_configured_parameters_reach_the_plan(tmp_path):
    cfg = config_from_mapping({"arm1dof.params.pc": 0.25, "library_path": str(tmp_path / "l.sqlite")})
    svc = PlannerService(cfg)
    checked = svc.make_request(RequestFields(model="arm1dof", q0=[0.0], qf=[1.0], move_time=1.0,
                                             override_names=["pv"], override_values=[-0.04]))
    req = checked.request
    p = req.resolved_params()
    assert (p.pc, p.pv) == (0.25, -0.04)
    assert req.starts == cfg.default_starts and req.time_budget == cfg.default_time_budget
    assert list(req.uncertain) == ["pv", "pc", "pt"] and req.objective == "robust-box"
    assert req.objective == cfg.default_objective and req.n_steps() == BOX_DEFAULT_STEPS and req.current_quantum == 0.0
    # a request while no workers run is answered, not raised
    res = svc.handle(checked)
    assert not res.success and res.error_code == "INTERNAL_ERROR"
    svc.close()
    (tmp_path / "file").write_text("")
    with pytest.raises(ServiceConfigError, match="library_path"):
        PlannerService(config_from_mapping({"library_path": str(tmp_path / "file" / "lib.sqlite")}))


@pytest.mark.integration
def test_service_warm_starts_from_the_nearest_stored_plan(tmp_path):
    cfg = ServiceConfig(library_path=str(tmp_path / "lib.sqlite"), workers=2, warmup=False,
                        warm_max_distance=0.2, switch_grid=0.0)     # the stub plans off any grid
    svc = PlannerService(cfg, plan_fn=stub_plan)
    svc.start()
    try:
        base = dict(model="arm1dof", q0=[0.0], move_time=1.0, uncertain=["pc"],
                    objective="robust-derivative")
        # a stored neighbour with recognisable currents (as ff-library build would leave it)
        seed_req = svc.make_request(RequestFields(qf=[1.0], **base)).request
        stored = stub_plan(seed_req, initial_currents=np.array([[3.0], [-1.0], [2.0]]))
        with MotionLibrary(cfg.library_path) as lib:
            assert lib.put(record_from_result(seed_req, stored), seed_req.resolved_params())
        near = svc.handle_fields(RequestFields(qf=[1.1], **base))
        assert near.success and near.warm_start and near.extra["source"] == "warm"
        assert near.extra.get("got_initial") is True
        np.testing.assert_array_equal(near.profile.currents, [[3.0], [-1.0], [2.0]])
        far = svc.handle_fields(RequestFields(qf=[1.5], **base))
        assert far.success and not far.warm_start and far.extra["source"] == "cold"
        again = svc.handle_fields(RequestFields(qf=[1.1], **base))      # now stored: a hit
        assert again.warm_start and again.extra["source"] == "hit"
        stats = svc.stats()
        assert stats["source_warm"] == 1 and stats["source_cold"] == 1 and stats["source_hit"] == 1
        assert stats["library_solved"] == 3
        # a stored "no robust plan here" answers at once when its search was as thorough as asked
        hard_req = svc.make_request(RequestFields(qf=[-2.0], starts=100, **base)).request
        none_found = stub_plan(hard_req)
        none_found.success, none_found.robust, none_found.error_code = False, False, "NO_ROBUST_PLAN"
        none_found.starts_tried = 100
        with MotionLibrary(cfg.library_path) as lib:
            assert lib.put(record_from_result(hard_req, none_found))
        known = svc.handle_fields(RequestFields(qf=[-2.0], starts=100, **base))
        assert not known.success and known.error_code == "NO_ROBUST_PLAN" and known.extra["source"] == "hit"
        assert "known from the motion library" in known.message
        deeper = svc.handle_fields(RequestFields(qf=[-2.0], starts=400, **base))   # more starts: solve
        assert deeper.success and deeper.extra["source"] == "cold"
        after = svc.handle_fields(RequestFields(qf=[-2.0], starts=100, **base))    # upgraded row
        assert after.success and after.extra["source"] == "hit"
    finally:
        svc.close()


# --- invalid requests are answered at once, with their error code --------------------------------
ONE_DOF = dict(model="arm1dof", q0=[0.0], qf=[1.0], move_time=1.0, objective="time-optimal")

BAD = [
    (dict(ONE_DOF, model="arm7dof"), "UNKNOWN_MODEL", "known models"),
    (dict(ONE_DOF, override_names=["friction"], override_values=[0.1]), "UNKNOWN_PARAMETER", "valid keys"),
    (dict(ONE_DOF, override_names=["pc"], override_values=[]), "INVALID_REQUEST", "override"),
    (dict(ONE_DOF, objective="robust-derivative", uncertain=["pq"]), "UNKNOWN_PARAMETER", "pq"),
    (dict(ONE_DOF, qf=[float("nan")]), "INVALID_REQUEST", "finite"),
    (dict(ONE_DOF, move_time=0.04), "INVALID_REQUEST", "coast"),
    (dict(ONE_DOF, qf=[1.0, 2.0]), "INVALID_REQUEST", "qf needs 1"),
    (dict(ONE_DOF, model="scara2"), "INVALID_REQUEST", "q0 needs 2"),
    (dict(ONE_DOF, qf=[40.0]), "UNREACHABLE", "raise tf"),
    (dict(ONE_DOF, steps=100000), "INVALID_REQUEST", "steps"),
    (dict(ONE_DOF, starts=10 ** 9), "INVALID_REQUEST", "starts"),
    (dict(ONE_DOF, time_budget=1e9), "INVALID_REQUEST", "time_budget"),
]


@pytest.fixture(scope="module")
def idle_service():
    """A service without a library or workers: only requests refused before planning are answered."""
    svc = PlannerService(ServiceConfig(max_steps=30))
    yield svc
    svc.close()


@pytest.mark.parametrize("fields, code, text", BAD, ids=[f"{c}-{t}" for _, c, t in BAD])
def test_bad_requests_get_their_error_code_without_planning(idle_service, fields, code, text):
    res = idle_service.handle_fields(RequestFields(**fields))
    assert not res.success and res.error_code == code, (res.error_code, res.message)
    assert text in res.message and res.extra["source"] == "invalid"


# --- the service answers from a library built by ff-library build ----------------------------------
GRID = {
    "model": "arm1dof", "preset": "table2", "objective": "robust-derivative", "uncertain": ["pc"],
    "starts": 200, "seed": 3, "time_budget": 60,
    "q0": [0.0, 0.25], "qf": {"start": 0.5, "stop": 1.25, "step": 0.25}, "tf": [0.9, 1.0],
    "switch_grid": 0.001,      # the node's default grid: its rows answer the node's requests
}


@pytest.mark.integration
def test_planner_service_answers_grid_requests_warm_from_the_library(tmp_path):
    from ff_planner.library.build import build_library
    from ff_planner.library.grid import expand, parse_grid

    path = tmp_path / "lib.sqlite"
    build_library(expand(parse_grid(GRID)), path, serial=True, progress=False)
    svc = PlannerService(ServiceConfig(library_path=str(path), workers=1, warmup=False))
    try:
        # a grid task (and a shifted copy of one): answered from the library without planning
        for q0, qf in ((0.0, 0.75), (0.25, 1.0), (1.0, 1.75)):
            res = svc.handle_fields(RequestFields(model="arm1dof", q0=[q0], qf=[qf], move_time=1.0,
                                                  uncertain=["pc"], starts=200,
                                                  objective="robust-derivative"))
            assert res.success and res.warm_start, res.message
            assert res.extra["source"] in ("hit", "shift") and "motion library" in res.message
            assert on_grid(res.profile, 0.001) and res.certificate is not None
            assert len(res.extra["predicted_rest"]) == 1 and abs(res.extra["predicted_rest"][0] - qf) < 1e-4
            assert res.extra["latency"] < 5.0
        # a request between grid points: re-optimised from the nearest stored plan (worker process)
        svc.start()
        res = svc.handle_fields(RequestFields(model="arm1dof", q0=[0.0], qf=[0.85], move_time=0.95,
                                              uncertain=["pc"], starts=200,
                                              objective="robust-derivative"))
        assert res.success and res.warm_start and res.extra["source"] == "warm", res.message
        assert "warm start from library entry" in res.message
    finally:
        svc.close()

"""Warm starts (ff_planner.library.warm): a stored neighbour's currents handed to the planner."""
from __future__ import annotations

import numpy as np
import pytest

from ff_planner.core.errors import WarmStartUnavailable
from ff_planner.library.store import MotionLibrary, record_from_result
from ff_planner.library.warm import warm_plan
from ff_planner.model.profile import CurrentProfile, PlanRequest, PlanResult


def _request(q0=0.0, qf=1.0, tf=1.0, **kw) -> PlanRequest:
    kw.setdefault("objective", "robust-derivative")
    return PlanRequest(model="arm1dof", q0=[q0], qf=[qf], tf=tf, uncertain=["pv", "pc", "pt"], **kw)


def _result(req: PlanRequest) -> PlanResult:
    prof = CurrentProfile.uniform(np.array([[1.0], [2.0], [-1.0], [0.5], [-2.5]]), req.tf)
    return PlanResult(success=True, message="", profile=prof, model=req.model, params=req.resolved_params(),
                      q0=np.asarray(req.q0, float), qf=np.asarray(req.qf, float), uncertain=list(req.uncertain),
                      objective=req.objective, q_final=np.asarray(req.qf, float), qd_final=np.zeros(1),
                      sensitivities={"pv": 1e-9, "pc": -2e-9, "pt": 0.0}, robust=True, starts_tried=10)


def test_warm_plan_hands_neighbour_currents_to_the_planner(tmp_path):
    with MotionLibrary(tmp_path / "lib.sqlite") as lib:
        req = _request()
        lib.put(record_from_result(req, _result(req)))
        neighbour = lib.nearest(_request(qf=1.05))[0][1]
    seen = {}

    def planner(request, progress=None, initial_currents=None):
        seen["init"] = initial_currents
        return _result(request)

    res = warm_plan(_request(qf=1.05), neighbour.currents(), planner, warm_from=neighbour.task_key)
    np.testing.assert_array_equal(seen["init"], neighbour.currents())
    assert res.warm_start and res.extra["warm_from"] == neighbour.task_key

    def cold_only(request, progress=None, initial_currents=None):
        """A planner whose model has no warm start (the facade raises, e.g. for scara2)."""
        raise WarmStartUnavailable("plan_robust_scara2 takes no initial_currents")

    with pytest.raises(WarmStartUnavailable, match="initial_currents"):
        warm_plan(_request(qf=1.05), neighbour.currents(), cold_only)
    with pytest.raises(WarmStartUnavailable, match="currents"):
        warm_plan(_request(qf=1.05, steps=7), neighbour.currents(), planner)
    with pytest.raises(WarmStartUnavailable, match="currents"):
        warm_plan(_request(qf=1.05), None, planner)

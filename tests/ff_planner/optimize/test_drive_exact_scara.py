"""Drive-exact SCARA plans: the profile sent to the drive (switches on its SYNC grid, currents on
its unit) lands where the answer says, or the answer says it does not."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ff_planner.model import scara2
from ff_planner.model.profile import PlanRequest
from ff_planner.model.simulate import rest_position
from ff_planner.optimize import planner as planner_mod
from ff_planner.optimize.drive_grid import DriveCertificate, drive_grid_from_config, on_period, on_quantum
from ff_planner.optimize.planner import plan

CONFIG = Path(__file__).resolve().parents[3] / "config"
DRIVE = drive_grid_from_config(CONFIG / "bridge_sim_scara2.yaml")   # 3 mA at a 10 ms SYNC
#: the paper's section 4.2 task: its equal steps of 0.11875 s fall off a 10 ms grid
TASK = dict(model="scara2", q0=(-0.5, 0.0), qf=(0.5, 0.0), tf=1.0, objective="robust-derivative",
            uncertain=scara2.FRICTION_NAMES, starts=50, seed=0, time_budget=60.0)
#: rad: what rounding 16 currents to 3 mA may move joint 1's rest (measured 0.26 mrad)
ROUNDING_REST = 3e-3


def _nominal_rest_error(res) -> np.ndarray:
    rest = rest_position(res.params, res.profile, [float(x) for x in res.q0])
    return np.abs(rest - np.asarray(res.qf, dtype=float))


@pytest.mark.parametrize("objective", ["robust-derivative", "robust-box"])
def test_scara_drive_exact_plan_lands_at_the_goal(objective):
    res = plan(PlanRequest(**dict(TASK, objective=objective)), drive=DRIVE)
    assert res.success and res.robust, res.message
    prof = res.profile
    assert on_period(prof, DRIVE.period) and on_quantum(prof, DRIVE.quantum)
    info = res.extra["drive_exact"]
    assert info["max_switch_shift_s"] > 1e-3          # the grid did move the planned switches
    assert info["resolve"]["ok"] and info["landing_ok"]
    err = _nominal_rest_error(res)
    assert np.all(err <= np.asarray(info["rest_error_allowed_rad"]) + 1e-12)
    assert float(err.max()) <= ROUNDING_REST, err
    assert res.extra["rest_position"] == pytest.approx(
        rest_position(res.params, prof, list(res.q0)).tolist(), abs=1e-12)
    assert "solved again on the drive's SYNC grid" in res.message
    assert f"as sent to the drive: nominal rest error {float(err.max()) * 1e3:.3g} mrad" in res.message
    sens = scara2.sensitivities_scara2(res.params, prof, np.asarray(res.q0), scara2.FRICTION_NAMES,
                                       method="complex")
    worst = max(abs(v) for k, v in sens.items() if k.startswith("q") and not k.startswith("qd"))
    assert info["rounding"]["max_abs_derivative"] == pytest.approx(worst, rel=1e-9, abs=1e-15)
    assert f"max |dq(tf)/dp| = {worst:.2g}" in res.message
    assert isinstance(res.certificate, DriveCertificate)
    assert res.certificate.worst_rest_error >= float(err.max()) - 1e-9   # the box holds nominal


def test_scara_plan_that_cannot_be_solved_on_the_grid_is_not_called_robust(monkeypatch):
    """Without the re-solve (e.g. it does not verify), the snapped profile lands ~0.1 rad short:
    the answer must say so instead of success/robust."""
    monkeypatch.setattr(planner_mod, "resolve_on_times", lambda *a, **k: None)
    res = plan(PlanRequest(**TASK), drive=DRIVE)
    err = _nominal_rest_error(res)
    assert float(err.max()) > 0.01                    # the snapped profile really is off
    assert not res.success and not res.robust and res.best_effort
    assert res.error_code == "NO_ROBUST_PLAN"
    assert "NOT robust as sent to the drive" in res.message
    assert res.extra["drive_exact"]["landing_ok"] is False
    assert res.extra["drive_exact"]["rest_error_rad"][0] == pytest.approx(float(err[0]), abs=1e-9)


def test_the_node_s_request_for_the_scara_drive_lands_at_the_goal():
    """As the planner node builds it (empty uncertain = all six, node defaults, the drive from
    its ``drive_config``), planned as its worker plans it."""
    from ff_planner.service.planner_service import PlannerService, RequestFields, ServiceConfig

    svc = PlannerService(ServiceConfig(library_path="", warmup=False,
                                       drive_config=str(CONFIG / "bridge_sim_scara2.yaml")))
    try:
        checked = svc.make_request(RequestFields(model="scara2", q0=[-0.5, 0.0], qf=[0.5, 0.0],
                                                 move_time=1.0, objective="robust-derivative"))
    finally:
        svc.close()
    assert checked.drive is not None and checked.drive.period == pytest.approx(0.01)
    res = plan(checked)
    assert res.success and res.robust, res.message
    assert float(_nominal_rest_error(res).max()) <= ROUNDING_REST

"""``ff-identify`` offline: simulated measurement, records files, outputs, refusals (no ROS)."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest
import yaml

from ff_planner.cli.identify import main
from ff_planner.model.params import load_params
from ff_planner.model.profile import CurrentProfile


def test_simulate_then_fit_records(tmp_path, capsys):
    recs, yml, rep = tmp_path / "runs.json", tmp_path / "p.yaml", tmp_path / "rep"
    code = main(["--simulate", "--sim-set", "pc=0.23", "--sim-set", "pt=0.2", "--levels", "2",
                 "--save-records", str(recs), "--json"])
    assert code == 0
    first = json.loads(capsys.readouterr().out)
    assert first["estimates"]["pc"] == pytest.approx(0.23, rel=0.03)
    cfg = tmp_path / "plan.yaml"
    code = main(["--records", str(recs), "-o", str(yml), "--report", str(rep), "--plan-config", str(cfg),
                 "--json"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert out["estimates"] == first["estimates"]            # the same runs, the same fit
    lo, hi = out["interval95"]["pt"]
    assert lo <= 0.2 <= hi and out["truth"]["pt"] == 0.2
    assert load_params(yml).pc == pytest.approx(out["estimates"]["pc"])
    assert (rep / "report.txt").is_file() and (rep / "fit.png").is_file()
    plan = yaml.safe_load(cfg.read_text())
    assert plan["plan"]["box"] == pytest.approx(out["box"]) and plan["plan"]["uncertain"] == ["pv", "pc", "pt"]
    assert load_params({k: plan[k] for k in ("model", "preset", "params")}) == load_params(yml)
    assert out["ff_plan_box_args"].startswith("--box pv=")


@pytest.mark.integration     # a fresh interpreter in another process
def test_offline_entry_point_loads_no_ros():
    """The console script's module and the offline CLI import no rclpy (only --sim does)."""
    code = ("import sys, ff_executor.bringup.identify, ff_planner.cli.identify; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'ff_msgs')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize("argv, msg", [
    (["--sim"], "on-stack runner"),
    (["--simulate", "--q-min", "-0.01", "--q-max", "0.01"], "envelope too small"),
    (["--simulate", "--sim-set", "foo=1"], "unknown parameter"),
    (["--records", "/no/such/file.json"], "no such file"),
    (["--simulate", "--sim-set", "pc"], "KEY=VALUE"),
])
def test_bad_input_is_one_line_exit_2(argv, msg, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert msg in err and len(err.splitlines()) == 1


def test_sim_refuses_a_too_small_envelope_before_it_starts_anything(capsys):
    calls = []

    def runner(*args, **kwargs):            # the on-stack runner: starting it would move the arm
        calls.append((args, kwargs))
        raise AssertionError("the stack was started")

    assert main(["--sim", "--q-min", "-0.05", "--q-max", "0.05"], sim_runner=runner) == 2
    err = capsys.readouterr().err.strip()
    assert "envelope too small" in err and len(err.splitlines()) == 1 and calls == []


def test_sim_hands_the_friction_that_is_not_eq9_to_the_stack(capsys):
    seen = {}

    def runner(ex, base, true, q_start, log, measure="joints", friction=None):
        seen.update(friction=friction, true=true, runs=len(ex.runs))
        raise RuntimeError("stack not started in this test")

    assert main(["--sim", "--sim-set", "pc=0.2", "--sim-friction", "stribeck=0.3", "--levels", "2"],
                sim_runner=runner) == 1
    assert seen == {"friction": {"stribeck": 0.3}, "true": {"pc": 0.2}, "runs": 4}
    assert main(["--sim", "--sim-friction", "wobble=1"], sim_runner=runner) == 2
    assert "unknown key" in capsys.readouterr().err


def _motion_files(tmp_path):
    """Two energy-optimal baselines planned on table 2, written as ff-motion/1 files."""
    from ff_planner.export.motion_file import write_motion
    from ff_planner.model.profile import PlanRequest
    from ff_planner.optimize import plan

    out = []
    for i, (q0, qf, tf) in enumerate([(0.0, 1.0, 1.0), (1.0, 0.2, 0.6)]):
        res = plan(PlanRequest(q0=(q0,), qf=(qf,), tf=tf, objective="energy-optimal"))
        out.append((write_motion(tmp_path / f"m{i}.json", res), res.profile, q0))
    return out


def test_update_from_executions_round_trip(tmp_path, capsys):
    import numpy as np

    from ff_planner.identify.learn import load_prior
    from ff_planner.identify.measure import Sensors, measure_rest

    prior = tmp_path / "p.yaml"
    assert main(["--simulate", "--levels", "2", "--sim-set", "pc=0.2", "-o", str(prior)]) == 0
    capsys.readouterr()
    true = load_params(prior).replace(pc=0.2 * 1.001, pt=0.22 * 0.999)     # the friction drifted
    rng = np.random.default_rng(0)
    runs = []
    for path, prof, q0 in _motion_files(tmp_path):
        runs.append({"motion": path.name, "rest_position": measure_rest(true, prof, q0, rng, Sensors(), 5e-5)})
    runs.append({"motion": {"step_times": [0.0, 0.3, 0.6], "currents": [3.0, -3.0], "tf": 0.9, "coast": 0.3},
                 "q0": 0.2, "q_sigma": 1e-4,
                 "rest_position": measure_rest(true, CurrentProfile(np.array([0.0, 0.3, 0.6]), np.array([3.0, -3.0]),
                                                                     0.9, 0.3), 0.2, rng, Sensors(), 5e-5)})
    ex = tmp_path / "runs.json"
    ex.write_text(json.dumps(runs))
    # the identification's intervals (~1e-5 relative) rule out a 0.1 % drift: flagged
    assert main(["--update", str(prior), "--executions", str(ex), "--json"]) == 1
    flagged = json.loads(capsys.readouterr().out)
    assert not flagged["adequate"] and flagged["message"].startswith("INCONSISTENT")
    upd, cfg = tmp_path / "updated.yaml", tmp_path / "plan.yaml"
    code = main(["--update", str(prior), "--executions", str(ex), "--drift", "0.01", "-o", str(upd),
                 "--plan-config", str(cfg), "--report", str(tmp_path / "rep"), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0, out["message"]
    assert len(out["executions"]) == 3 and out["prior"]["covariance_from"] == "covariance + drift 0.01"
    assert all(e["information_bits"] > 1.0 for e in out["executions"])
    for k in ("pc", "pt"):
        lo, hi = out["interval95"][k]
        assert lo <= getattr(true, k) <= hi
        assert out["std"][k] < out["prior"]["std"][k]
    p2 = load_prior(upd)                        # the updated file is the next update's prior
    assert p2.params == load_params(upd) and p2.params.pc == pytest.approx(out["estimates"]["pc"])
    np.testing.assert_allclose(p2.cov, np.array(out["covariance"]), rtol=1e-5)
    assert yaml.safe_load(cfg.read_text())["plan"]["box"] == pytest.approx(out["box"])
    assert "bits" in (tmp_path / "rep" / "update.txt").read_text()


@pytest.mark.parametrize("runs, extra, msg", [
    (None, [], "needs --executions"),
    ([{"motion": "nope.json", "rest_position": 0.1}], [], "cannot read motion file"),
    ([{"motion": {"step_times": [0, 0.5], "currents": [1.0], "tf": 0.6, "q0": 0}}], [], "rest_position"),
    ("not json", [], "is not JSON"),
    ([{"motion": {"format": "ff-motion/1"}, "rest_position": 0.1}], [], "missing key"),
    ([], ["--q-sigma", "0"], "--q-sigma must be > 0"),
    ([], ["--drift", "-1"], "drift must be a fraction"),
])
def test_update_bad_input_is_one_line_exit_2(tmp_path, capsys, runs, extra, msg):
    prior = tmp_path / "p.yaml"
    prior.write_text("model: arm1dof\npreset: table2\n")
    argv = ["--update", str(prior), "--prior-box", "pv=0.3", "--prior-box", "pc=0.1", "--prior-box", "pt=0.1"]
    if runs is not None:
        ex = tmp_path / "runs.json"
        ex.write_text(runs if isinstance(runs, str) else json.dumps(runs))
        argv += ["--executions", str(ex)]
    assert main(argv + extra) == 2
    err = capsys.readouterr().err.strip()
    assert msg in err and len(err.splitlines()) == 1, err


def test_update_refuses_a_file_without_uncertainty_and_executions_without_update(tmp_path, capsys):
    prior = tmp_path / "p.yaml"
    prior.write_text("model: arm1dof\npreset: table2\n")
    ex = tmp_path / "runs.json"
    ex.write_text(json.dumps([{"motion": {"step_times": [0, 0.5], "currents": [3.0], "tf": 0.9, "q0": 0},
                               "rest_position": 0.1}]))
    assert main(["--update", str(prior), "--executions", str(ex)]) == 2
    assert "--prior-box" in capsys.readouterr().err
    assert main(["--simulate", "--executions", str(ex)]) == 2
    assert "needs --update" in capsys.readouterr().err

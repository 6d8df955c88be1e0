"""``ff-identify`` offline: simulated measurement, records files, outputs, refusals (no ROS)."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest
import yaml

from ff_planner.cli.identify import main
from ff_planner.model.params import load_params


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

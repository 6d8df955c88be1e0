"""ff-plan: exit codes, one-line errors (never a traceback), outputs."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from ff_planner.cli.plan import main
from ff_planner.export.motion_file import read_motion


@pytest.mark.parametrize("argv, needle", [
    (["--tf", "nan"], "--tf must be a finite"),
    (["--q0", "nan"], "finite"),
    (["--qf", "inf"], "finite"),
    (["--qf", "abc"], "not a number"),
    (["--tf", "0.05"], "must exceed the coast"),
    (["--tf", "0.03"], "must exceed the coast"),
    (["--qf", "40"], "UNREACHABLE"),
    (["--uncertain", "pq"], "unknown uncertain parameter"),
    (["--uncertain", "pc", "px"], "px"),
    (["--set", "foo=1"], "unknown parameter"),
    (["--set", "pc=-1"], "must be >= 0"),
    (["--set", "pc"], "KEY=VALUE"),
    (["--tf", "1e5"], "too long"),
    (["--tf", "1000"], "too long"),
    (["--set", "pc=0.3,0.19"], "give one number"),
    (["--qf", "-inf"], "finite"),
    (["--q0", "-nan"], "finite"),
    (["--steps", "-3"], "--steps must be >= 1"),
    (["--model", "scara2", "--qf", "1"], "needs 2 value"),
    (["--model", "robot"], "invalid choice"),
    (["--objective", "fast"], "invalid choice"),
    (["--params", "/nonexistent.yaml"], "no such file"),
    (["--preset", "table3", "--model", "arm1dof"], "for model 'scara2'"),
    (["-o", "/nonexistent-dir/x.json"], "does not exist"),
    (["--bogus"], "unrecognized arguments"),
    (["--time-budget", "1e-9"], "ran out before any plan was tried"),
    (["--drive-config", "/nonexistent/bridge.yaml"], "no bridge config file"),
    (["--drive-config", "config/bridge_epos4_1dof.yaml", "--current-quantum", "0.001"],
     "differs from the drive's setpoint unit"),
    (["--set", "pc=1e-300"], "never comes to rest"),
    (["--q0", "1e308", "--qf", "1e308"], "beyond ±10000 rad"),
    (["--set", "pt=1.5"], "pt must be < 1"),
    (["--tolerance", "0.002", "--tf", "1"], "not both"),
    (["--tf-max", "2"], "--tf-max bounds a --tolerance search"),
    (["--tolerance", "-1"], "--tolerance must be > 0"),
    (["--tolerance", "0.002", "--tf-max", "100"], "--tf-max must be in"),
    (["--q-min", "0.5"], "below --q-min"),
    (["--q-max", "0.5"], "above --q-max"),
    (["--q-min", "0", "0"], "one per joint"),
    (["--qd-max", "0"], "--qd-max must be > 0"),
    (["--q-min", "1", "--q-max", "0.5"], "must be below --q-max"),
    (["--qd-max", "x"], "not a number"),
])
def test_bad_input_one_line_exit_2(argv, needle, capsys):
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ff-plan: error")
    assert needle in lines[0]
    assert "Traceback" not in err


@pytest.mark.parametrize("option, text, needle", [
    ("--params", "model: arm1dof\nparams: {pc: [1, 2}\n", "cannot read"),
    ("--params", "model: arm1dof\nparams: {pz: 1}\n", "pz"),
    ("--config", "task: {qf: [1.0], speed: 3}\n", "speed"),
    ("--config", "plan: {steps: -2}\n", "--steps must be >= 1"),
    ("--config", "task: {tf: .nan}\n", "finite"),
], ids=["params-yaml", "params-key", "config-key", "config-steps", "config-nan"])
def test_bad_params_or_config_file_exit_2(option, text, needle, tmp_path, capsys):
    f = tmp_path / "bad.yaml"
    f.write_text(text)
    assert main([option, str(f)]) == 2
    assert needle in capsys.readouterr().err


def test_time_optimal_writes_motion_and_plot(tmp_path, capsys):
    out, png = tmp_path / "m.json", tmp_path / "m.png"
    rc = main(["--objective", "time-optimal", "--qf", "0.8", "-o", str(out), "--plot", str(png)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "time-optimal" in text and "wrote" in text
    m = read_motion(out)
    assert m.qf[0] == 0.8 and m.extra["objective"] == "time-optimal"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_json_summary_and_params_file(tmp_path, capsys):
    f = tmp_path / "p.yaml"
    f.write_text("preset: table2\nparams: {pc: 0.2}\n")
    rc = main(["--params", str(f), "--objective", "energy-optimal", "--steps", "20", "--json",
               "-o", str(tmp_path / "e.json")])
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    assert d["objective"] == "energy-optimal" and d["success"] and not d["robust"]
    assert read_motion(tmp_path / "e.json").params.pc == 0.2
    assert abs(d["q_final"][0] - 1.0) < 1e-8


def test_drive_config_plans_drive_exact(tmp_path, capsys):
    out = tmp_path / "d.json"
    rc = main(["--objective", "robust-derivative", "--drive-config",
               "config/bridge_epos4_1dof.yaml", "--json", "-o", str(out)])
    d = json.loads(capsys.readouterr().out)
    assert rc == (0 if d["success"] else 1)
    drive = d["certificate"]["drive"]
    assert drive["current_quantum_A"] == 0.003 and drive["switch_period_s"] == 0.01
    assert d["drive_exact"]["on_grid"] and d["drive_exact"]["on_quantum"]
    m = json.loads(out.read_text())
    assert m["certificate"]["drive"] == drive          # the motion file says what was certified
    k = [t / 0.01 for t in m["step_times"]]
    assert all(abs(x - round(x)) < 1e-9 for x in k)
    assert all(abs(i / 0.003 - round(i / 0.003)) < 1e-6 for row in m["currents"] for i in row)


def test_drive_config_from_a_plan_file_and_printed(tmp_path, capsys):
    f = tmp_path / "plan.yaml"
    f.write_text("plan: {objective: time-optimal, uncertain: [pc], "
                 "drive_config: config/bridge_epos4_1dof.yaml}\n")
    assert main(["--config", str(f)]) == 0
    text = capsys.readouterr().out
    assert "drive-exact: 3 mA steps, 10 ms SYNC" in text
    assert "certificate computed on the profile sent to the drive" in text


@pytest.mark.integration
def test_help_via_subprocess():
    r = subprocess.run([sys.executable, "-m", "ff_planner.cli.plan", "--help"], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0
    for flag in ("--q0", "--qf", "--tf", "--uncertain", "--objective", "--steps", "--starts",
                 "--seed", "--time-budget", "--output", "--plot"):
        assert flag in r.stdout


@pytest.mark.integration
def test_unreachable_via_subprocess_no_traceback():
    r = subprocess.run([sys.executable, "-m", "ff_planner.cli.plan", "--qf", "1e3"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.count("\n") == 1 and "UNREACHABLE" in r.stderr


def test_config_files_load_and_flags_override():
    from pathlib import Path

    from ff_planner.cli.plan import build_parser, make_request

    cfgdir = Path(__file__).resolve().parents[3] / "config"
    files = sorted(cfgdir.glob("plan_*.yaml"))
    assert len(files) >= 3
    for f in files:   # every shipped example parses into a valid request
        req = make_request(build_parser().parse_args(["--config", str(f)]))
        req.validate()
    req = make_request(build_parser().parse_args(
        ["--config", str(cfgdir / "plan_arm1dof_k3.yaml"), "--qf", "0.5", "--steps", "7"]))
    assert req.qf == (0.5,) and req.steps == 7 and req.starts == 100
    assert req.uncertain == ("pv", "pc", "pt") and req.params.pc == 0.19


def test_progress_printer_is_quiet_at_first_then_throttled():
    import io

    from ff_planner.cli.plan import ProgressPrinter

    out = io.StringIO()
    pp = ProgressPrinter(delay=0.0, every=3600.0, stream=out)
    pp({"starts_done": 10, "best": 1e-3, "stage": "joint1"})
    pp({"starts_done": 20, "best": 1e-4})          # within the throttle window: dropped
    text = out.getvalue()
    assert pp.lines == 1 and "starts_done=10" in text and "best=0.001" in text and "stage=joint1" in text
    quiet = ProgressPrinter(delay=3600.0, stream=out)
    quiet({"starts_done": 1})
    assert quiet.lines == 0


def test_negative_exponent_values_are_values(capsys):
    """A value such as -1e-1 after --qf is a number, not an option."""
    assert main(["--qf", "-1e-1", "--objective", "energy-optimal", "--json", "--quiet"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert abs(d["rest_position"][0] + 0.1) < 1e-6


def test_certificate_printed_and_written(tmp_path, capsys):
    out = tmp_path / "m.json"
    assert main(["--objective", "energy-optimal", "-o", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "worst rest error" in text and "moving at tf" in text
    cert = json.loads(out.read_text())["certificate"]
    assert cert["worst_rest_error"] > 0.1      # the energy-optimal plan is not robust
    assert set(cert["per_parameter"]) == {"pv", "pc", "pt"}
    assert len(cert["switch_timing_per_100us"]) == len(json.loads(out.read_text())["currents"])


def test_help_states_the_default_steps_and_the_new_options(capsys):
    from ff_planner.model.profile import BOX_DEFAULT_STEPS

    assert main(["--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert f"robust-box {BOX_DEFAULT_STEPS}," in text
    for flag in ("--q-min", "--q-max", "--qd-max", "--tolerance", "--tf-max"):
        assert flag in text


def test_json_stays_json_when_the_arm_never_rests(capsys):
    """A best-effort plan whose rest position and certificate are not finite: strict JSON."""
    rc = main(["--tf", "60", "--qf", "1000", "--objective", "robust-derivative", "--json",
               "--quiet"])
    out = capsys.readouterr().out

    def refuse(name):
        raise AssertionError(f"{name} in the JSON output")

    d = json.loads(out, parse_constant=refuse)
    assert rc == 1 and not d["success"]
    assert "a longer move time" not in d["message"] and "at its maximum of 60 s" in d["message"]


def test_limits_reach_the_request_and_a_broken_limit_is_labelled(monkeypatch, capsys):
    from dataclasses import replace

    import ff_planner.optimize.planner as planner
    from ff_planner.cli.plan import build_parser, make_request
    from ff_planner.optimize.baselines import plan_baseline

    req = make_request(build_parser().parse_args(
        ["--q-min", "-0.3", "--q-max", "1.05", "--qd-max", "4"]))
    assert req.limits.position_min == (-0.3,) and req.limits.position_max == (1.05,)
    assert req.limits.velocity_max == (4.0,)
    assert make_request(build_parser().parse_args([])).limits is None
    # a planner that ignores the limits: its plan (certified by the facade) is labelled, exit 1,
    # the swing printed; a 0.5 rad/s speed limit cannot hold for 1 rad in 1 s
    monkeypatch.setitem(planner.ROUTES, ("arm1dof", "energy-optimal"), planner.Route(
        lambda req, progress: plan_baseline(replace(req, limits=None), progress), False))
    rc = main(["--objective", "energy-optimal", "--qd-max", "0.5", "--quiet"])
    text = capsys.readouterr().out
    assert rc == 1
    assert "excursion until rest" in text and "LIMITS BROKEN" in text and "velocity_max 0.5" in text


def test_tolerance_search_request_and_answer(monkeypatch, capsys):
    """--tolerance plans through the tf search and prints every tf it tried."""
    from ff_planner.cli.plan import build_parser, make_request

    req = make_request(build_parser().parse_args(["--tolerance", "0.002", "--tf-max", "2"]))
    assert req.tolerance == 0.002 and req.move_time_max == 2.0 and req.tf == 2.0
    rc = main(["--tolerance", "0.7", "--tf-max", "1.5", "--objective", "energy-optimal",
               "--json", "--quiet"])
    d = json.loads(capsys.readouterr().out)
    search = d["tolerance_search"]
    assert rc == 0 and d["success"] and search["met"]
    assert d["certificate"]["worst_rest_error"] <= 0.7
    tfs = [t["tf"] for t in search["trials"]]
    assert len(tfs) >= 3 and tfs[0] == 1.5
    passed = [t["tf"] for t in search["trials"] if t["meets"]]
    failed = [t["tf"] for t in search["trials"] if not t["meets"]]
    assert d["steps"] and min(passed) == search["bracket"][1]
    assert search["bracket"][1] - search["bracket"][0] <= 0.01 * search["bracket"][1] + 1e-3
    assert max(failed) == 1.5                 # the energy-optimal plan strays more when slower
    assert "fastest tf certified within 700 mrad" in d["message"]
    assert main(["--tolerance", "0.7", "--tf-max", "1.5", "--objective", "energy-optimal",
                 "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "tolerance search (700 mrad, tf <= 1.5 s)" in text and "tf 1.500 s: certified" in text


def test_tradeoff_table_json_and_plot(tmp_path, capsys):
    png = tmp_path / "t.png"
    rc = main(["--objective", "energy-optimal", "--qd-max", "1.5", "--tradeoff", str(png),
               "--tradeoff-points", "3", "--tf-max", "1.5", "--json", "--quiet"])
    d = json.loads(capsys.readouterr().out)
    assert rc == 0 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rows = d["tradeoff"]
    assert [r["label"] for r in rows] == ["no limits"] * 3 + ["limits"] * 3
    assert rows[2]["tf"] == 1.5 and rows[0]["tf"] < rows[1]["tf"] < 1.5
    planned = [r for r in rows if r["worst_rest_error"] is not None]
    assert len(planned) >= 3          # at the reach bound (and under the limits) maybe none
    assert all(r["worst_rest_error"] > 0 and len(r["worst_speed"]) == 1 for r in planned)
    free = {r["tf"]: r for r in rows if r["label"] == "no limits"}
    limited = {r["tf"]: r for r in rows if r["label"] == "limits"}
    for r in limited.values():        # over the speed limit: never a success
        if r["worst_speed"]:
            assert r["success"] == (r["worst_speed"][0] <= 1.5 + 1e-9)
    mid = sorted(free)[1]
    assert free[mid]["worst_speed"][0] > 1.5 and not limited[mid]["success"]
    assert main(["--tradeoff", str(png), "--tradeoff-points", "1"]) == 2


def test_no_time_for_a_single_start_is_a_clear_no_plan(capsys):
    rc = main(["--objective", "robust-derivative", "--time-budget", "1e-9", "--quiet"])
    out, err = capsys.readouterr()
    assert rc == 1 and err == ""
    lines = out.strip().splitlines()
    assert len(lines) == 2 and "NO PLAN [TIME_BUDGET_EXHAUSTED]" in lines[0]

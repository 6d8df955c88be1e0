"""``ff-plan``: plan a robust (or baseline) feedforward move from the command line.

Writes an ff-motion/1 file (``-o``), optionally a Fig. 5/7-style PNG (``--plot``), and prints a
short summary. Exit codes: 0 plan found and meets its tolerances; 1 only a best-effort plan
(written, labelled) or an internal error; 2 bad input or unreachable goal (one error line).
"""
from __future__ import annotations

import argparse
import functools
import json
import math
import sys
import time
from pathlib import Path
from typing import NoReturn, Optional, Sequence

import numpy as np

from ff_planner.export.motion_file import jsonable
from ff_planner.model.limits import MotionLimits
from ff_planner.model.params import DEFAULT_PRESET, MODELS, PRESETS, ParameterError, load_params, n_joints, preset
from ff_planner.model.profile import (BOX_DEFAULT_STEPS, DEFAULT_COAST, DEFAULT_COAST_MAX, MAX_TF, OBJECTIVES,
                                      PlanningError, PlanRequest)

PROG = "ff-plan"


class UsageError(Exception):
    """Bad command-line input (exit code 2)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:  # one line, exit 2 (argparse prints usage + error)
        raise UsageError(f"{message} (see {PROG} --help)")


def _floats(values: Sequence[str], name: str) -> list[float]:
    out: list[float] = []
    for v in values:
        for part in str(v).replace(",", " ").split():
            try:
                x = float(part)
            except ValueError:
                raise UsageError(f"{name}: {part!r} is not a number") from None
            if not math.isfinite(x):
                raise UsageError(f"{name}: values must be finite numbers, got {part!r}")
            out.append(x)
    if not out:
        raise UsageError(f"{name}: give at least one number")
    return out


def _names(values: Optional[Sequence[str]]) -> Optional[list[str]]:
    if values is None:
        return None
    return [p for v in values for p in str(v).replace(",", " ").split()]


def build_parser(tolerance_search: bool = True, tradeoff: bool = True,
                 drive: Optional[bool] = None) -> argparse.ArgumentParser:
    """ff-plan's parser; ``tolerance_search=False`` leaves out --tolerance and --tf-max (for a
    command whose own --tolerance means something else), ``tradeoff=False`` --tradeoff (for a
    command that plans through a service); ``drive`` (default: as ``tradeoff``) adds
    --drive-config (in-process plans; a service takes its drive from its own configuration)."""
    p = _Parser(
        prog=PROG,
        description="Plan a rest-to-rest feedforward current profile whose final position is "
                    "insensitive to friction-model errors (Plooij et al.), or a time/energy-"
                    "optimal baseline. Units: rad, s, A.",
        epilog="examples:\n"
               "  ff-plan --qf 1 --tf 1 --uncertain pv pc pt -o move.json --plot move.png\n"
               "  ff-plan --preset table1 --uncertain pc --steps 3 -o coulomb.json\n"
               "  ff-plan --model scara2 --q0 -0.5 0 --qf 0.5 0 --uncertain pv1 pc1 pt1 pv2 pc2 pt2\n"
               "  ff-plan --objective energy-optimal --qf 1 -o energy.json\n"
               "  ff-plan --qf 1 --tf 1 --q-min -0.3 --q-max 1.05 --qd-max 4   # limits, whole box\n"
               "  ff-plan --qf 1 --tolerance 0.002 --tf-max 3   # the fastest tf certified within 2 mrad\n"
               "  ff-plan --qf 1 --drive-config config/bridge_epos4_1dof.yaml -o move.json   # drive-exact\n"
               "  ff-plan --cell config/arms/arm3h.cell.yaml --q0 0,0,0 --qf 0.5,-0.4,0.6 --tf 1.5  # an arm\n"
               "      from a URDF + cell file (docs/arms.md; ff-plan --cell X --help for its options)\n"
               "exit codes: 0 plan meets its tolerances; 1 best-effort plan only (still written)\n"
               "or internal error; 2 bad input or unreachable goal.",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    m = p.add_argument_group("model")
    m.add_argument("--model", choices=sorted(MODELS), default=None,
                   help="model id (default arm1dof, or the preset's / params file's model)")
    m.add_argument("--preset", choices=sorted(PRESETS), default=None,
                   help="paper parameter set: table1 (Coulomb only), table2 (1-DOF), table3 (SCARA)")
    m.add_argument("--params", metavar="YAML", default=None,
                   help="parameter file {model:, preset:, params: {key: value}} (SI units)")
    m.add_argument("--config", metavar="YAML", default=None,
                   help="plan file: model/preset/params plus task: {q0, qf, tf, coast, q_min, "
                        "q_max, qd_max, tolerance, tf_max} and "
                        "plan: {uncertain, objective, steps, starts, seed, time_budget, tol, "
                        "box, coast_max, current_quantum}; "
                        "command-line flags override it (examples in config/plan_*.yaml)")
    m.add_argument("--set", metavar="KEY=VALUE", action="append", default=[],
                   help="override one model parameter, e.g. --set pc=0.22 (repeatable)")
    t = p.add_argument_group("task")
    t.add_argument("--q0", nargs="+", default=None, metavar="RAD",
                   help="start position per joint (default 0, or -0.5 0 for scara2)")
    t.add_argument("--qf", nargs="+", default=None, metavar="RAD",
                   help="goal position per joint (default 1, or 0.5 0 for scara2)")
    t.add_argument("--tf", type=float, default=None, metavar="S",
                   help="move time (default 1 s; with --tolerance the planner chooses it)")
    t.add_argument("--coast", type=float, default=None, metavar="S",
                   help=f"zero-current coast at the end (default {DEFAULT_COAST} s)")
    t.add_argument("--q-min", nargs="+", default=None, metavar="RAD",
                   help="lowest position per joint, held along the whole motion (until rest) at "
                        "every point of the friction box (default: none)")
    t.add_argument("--q-max", nargs="+", default=None, metavar="RAD",
                   help="highest position per joint, likewise (default: none)")
    t.add_argument("--qd-max", nargs="+", default=None, metavar="RAD/S",
                   help="speed limit |qd| per joint, likewise (default: none)")
    if tolerance_search:
        t.add_argument("--tolerance", type=float, default=None, metavar="RAD",
                       help="certified worst rest error wanted over the friction box: plan the "
                            "fastest tf <= --tf-max that meets it (instead of --tf)")
        t.add_argument("--tf-max", type=float, default=None, metavar="S",
                       help="with --tolerance or --tradeoff: the longest move time to "
                            "consider (default 3 s)")
    o = p.add_argument_group("optimisation")
    o.add_argument("--uncertain", nargs="+", default=None, metavar="NAME",
                   help="friction parameters to be robust to (default: all of the model's)")
    o.add_argument("--objective", choices=OBJECTIVES, default=None,
                   help="robust-box (default: least worst rest error over the friction box, "
                        "among plans with zero exact derivatives), robust-derivative (the paper's "
                        "zero derivatives alone), robust-sampled, time-optimal, energy-optimal")
    o.add_argument("--steps", type=int, default=None, metavar="N",
                   help=f"current steps per joint (default: robust-box {BOX_DEFAULT_STEPS}, "
                        f"and only while no truly robust plan is found there the others from 2 + "
                        f"number of uncertain parameters up to 12; other objectives 2 + number of "
                        f"uncertain parameters; 0: the robust 1-DOF planner chooses the smallest "
                        f"N up to 12, robust-box until the box worst is <= 5 mrad)")
    o.add_argument("--starts", type=int, default=None,
                   help="multistart count (default 50; 0: escalated 50 -> 200 -> 1000)")
    o.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    o.add_argument("--box", metavar="KEY=FRACTION", action="append", default=None,
                   help="robust-box and the certificate: ± fraction of one uncertain parameter, "
                        "e.g. --box pc=0.3 (repeatable; default 0.2 each)")
    o.add_argument("--coast-max", type=float, default=None, metavar="S",
                   help="robust-box: longest coast the planner may choose (default 0.25 s)")
    o.add_argument("--current-quantum", type=float, default=None, metavar="A",
                   help="round the plan's currents to this grid, the drive's setpoint unit "
                        "(EPOS4: nominal current / 1000, e.g. 0.003); rest position and "
                        "certificate are for the rounded profile (default 0 = none)")
    if tradeoff if drive is None else drive:
        o.add_argument("--drive-config", metavar="YAML", default=None,
                       help="plan for the drive of this bridge config (config/bridge_*.yaml, the "
                            "file the bridge runs with): currents in its setpoint unit (EPOS4: "
                            "nominal current / 1000), switch times on its SYNC grid (sync_period), "
                            "certificate computed on exactly that profile (plan-file key "
                            "plan: {drive_config: ...}; default: none)")
    o.add_argument("--time-budget", type=float, default=None, metavar="S",
                   help="wall-clock budget for the whole plan, every N tried (and with "
                        "--tolerance every tf tried) included (default 30 s); the best plan so far "
                        "is returned")
    o.add_argument("--tol", type=float, default=None,
                   help="robustness tolerance on |dq(tf)/dp| and |q(tf)-qf| (default 1e-6)")
    out = p.add_argument_group("output")
    out.add_argument("-o", "--output", metavar="JSON", default=None, help="write the motion file")
    out.add_argument("--plot", metavar="PNG", default=None,
                     help="write a figure: current, position at nominal and ±40 %% friction, "
                          "final position vs parameter change")
    if tradeoff:
        out.add_argument("--tradeoff", metavar="PNG", default=None,
                         help="instead of one plan: plan the move at --tradeoff-points move times "
                              "up to --tf-max (default 3 s), without limits and under the given "
                              "ones; print certified worst rest error and excursion per tf and "
                              "plot them")
        out.add_argument("--tradeoff-points", type=int, default=8, metavar="N",
                         help="move times in the trade-off (default 8)")
    out.add_argument("--json", action="store_true", help="print the summary as JSON")
    out.add_argument("--debug", action="store_true", help="show tracebacks of internal errors")
    out.add_argument("--quiet", action="store_true",
                     help="no progress lines on stderr (shown once a plan runs longer than 1 s)")
    return p


class ProgressPrinter:
    """Progress lines on stderr for long plans: nothing in the first ``delay`` s, then one line
    at most every ``every`` s (elapsed time, starts done, best residual, stage)."""

    def __init__(self, delay: float = 1.0, every: float = 1.0, stream=None) -> None:

        self._clock = time.monotonic
        self._t0 = self._clock()
        self._next = self._t0 + delay
        self._every = every
        self._stream = stream if stream is not None else sys.stderr
        self.lines = 0

    def __call__(self, info: dict) -> None:
        now = self._clock()
        if now < self._next:
            return
        self._next = now + self._every
        parts = [f"{now - self._t0:6.1f} s"]
        for key in ("stage", "starts_done", "robust_found", "best", "robust"):
            if key in info:
                v = info[key]
                parts.append(f"{key}={v:.3g}" if isinstance(v, float) else f"{key}={v}")
        print(f"{PROG}: " + "  ".join(parts), file=self._stream, flush=True)
        self.lines += 1


DEFAULTS = {"tf": 1.0, "coast": DEFAULT_COAST, "objective": PlanRequest().objective, "starts": 50,
            "seed": 0, "time_budget": 30.0, "tol": 1e-6, "coast_max": DEFAULT_COAST_MAX,
            "current_quantum": 0.0}
_TASK_KEYS = ("q0", "qf", "tf", "coast", "q_min", "q_max", "qd_max", "tolerance", "tf_max")
DEFAULT_TF_MAX = 3.0    # s, longest move time a --tolerance search considers
_PLAN_KEYS = ("uncertain", "objective", "steps", "starts", "seed", "time_budget", "tol", "box",
              "coast_max", "current_quantum", "drive_config")


def load_config(path: str) -> dict:
    """Read a plan file (YAML); UsageError naming the problem if it is malformed."""
    import yaml

    if not Path(path).is_file():
        raise UsageError(f"--config: no such file {path!r}")
    try:
        with open(path, "r", encoding="utf-8") as fh:
            cfg = yaml.safe_load(fh) or {}
    except Exception as e:
        raise UsageError(f"--config: cannot read {path!r}: {e}".splitlines()[0]) from None
    if not isinstance(cfg, dict):
        raise UsageError(f"--config: {path!r} must hold a mapping")
    extra = set(cfg) - {"model", "preset", "params", "task", "plan"}
    if extra:
        raise UsageError(f"--config: unexpected key(s) {sorted(extra)}; expected model, preset, "
                         f"params, task, plan")
    for sect, keys in (("task", _TASK_KEYS), ("plan", _PLAN_KEYS)):
        sub = cfg.get(sect) or {}
        if not isinstance(sub, dict):
            raise UsageError(f"--config: '{sect}' must be a mapping")
        bad = set(sub) - set(keys)
        if bad:
            raise UsageError(f"--config: unknown {sect} key(s) {sorted(bad)}; expected {list(keys)}")
    return cfg


def _resolve_params(args: argparse.Namespace, cfg: dict):
    if args.params and args.preset:
        raise UsageError("give --params or --preset, not both (a params file can name a preset)")
    if args.params:
        if not Path(args.params).is_file():
            raise UsageError(f"--params: no such file {args.params!r}")
        try:
            base = load_params(args.params)
        except ParameterError:
            raise
        except Exception as e:  # YAML syntax errors and the like
            raise UsageError(f"--params: cannot read {args.params!r}: {e}".splitlines()[0]) from None
    elif args.preset:
        base = preset(args.preset)
    elif cfg and ({"model", "preset", "params"} & set(cfg)):
        base = load_params({k: cfg[k] for k in ("model", "preset", "params") if k in cfg})
    else:
        base = PRESETS[DEFAULT_PRESET[args.model or "arm1dof"]]
    if args.model and base.model != args.model:
        raise UsageError(f"the parameters are for model '{base.model}', not --model {args.model}")
    overrides = {}
    for item in args.set:
        if "=" not in item:
            raise UsageError(f"--set expects KEY=VALUE, got {item!r}")
        k, v = item.split("=", 1)
        vals = _floats([v], f"--set {k.strip()}")
        if len(vals) != 1:
            raise UsageError(f"--set {k.strip()}: give one number, got {v.strip()!r}")
        overrides[k.strip()] = vals[0]
    return base.replace(**overrides) if overrides else base


def _pick(args: argparse.Namespace, cfg: dict, key: str):
    """Flag value, else the plan file's, else the built-in default."""
    v = getattr(args, key, None)
    if v is not None:
        return v
    for sect in ("task", "plan"):
        sub = cfg.get(sect) or {}
        if key in sub:
            return sub[key]
    return DEFAULTS.get(key)


def _number(v, name: str, kind=float):
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        try:
            v = kind(str(v))
        except ValueError:
            raise UsageError(f"{name} must be a number, got {v!r}") from None
    if not math.isfinite(float(v)):
        raise UsageError(f"{name} must be a finite number, got {v!r}")
    if kind is int and float(v) != int(v):
        raise UsageError(f"{name} must be a whole number, got {v!r}")
    return kind(v)


def _box(v) -> Optional[dict]:
    """--box KEY=FRACTION items (or the plan file's mapping) as {key: fraction}."""
    if v is None:
        return None
    if isinstance(v, dict):
        return {str(k): _number(x, f"--box {k}") for k, x in v.items()}
    out = {}
    for item in v:
        if "=" not in str(item):
            raise UsageError(f"--box expects KEY=FRACTION, got {item!r}")
        k, x = str(item).split("=", 1)
        vals = _floats([x], f"--box {k.strip()}")
        if len(vals) != 1:
            raise UsageError(f"--box {k.strip()}: give one number, got {x.strip()!r}")
        out[k.strip()] = vals[0]
    return out


def make_request(args: argparse.Namespace) -> PlanRequest:
    """The PlanRequest for parsed arguments (UsageError / ParameterError on bad input)."""
    cfg = load_config(args.config) if args.config else {}
    params = _resolve_params(args, cfg)
    model = params.model
    nj = n_joints(model)

    def vec(key: str, default: list[float]) -> list[float]:
        v = _pick(args, cfg, key)
        if v is None:
            return default
        return _floats([str(x) for x in (v if isinstance(v, (list, tuple)) else [v])],
                       f"--{key.replace('_', '-')}")

    q0 = vec("q0", [0.0] if nj == 1 else [-0.5, 0.0])
    qf = vec("qf", [1.0] if nj == 1 else [0.5, 0.0])
    for name, v in (("--q0", q0), ("--qf", qf)):
        if len(v) != nj:
            raise UsageError(f"{name} needs {nj} value(s) for model '{model}', got {len(v)}")
    tolerance, tf_max = _tolerance(args, cfg)
    tf = _number(_pick(args, cfg, "tf"), "--tf") if tolerance is None else tf_max
    coast = _number(_pick(args, cfg, "coast"), "--coast")
    time_budget = _number(_pick(args, cfg, "time_budget"), "--time-budget")
    tol = _number(_pick(args, cfg, "tol"), "--tol")
    for name, x in (("--tf", tf), ("--coast", coast), ("--time-budget", time_budget),
                    ("--tol", tol)):
        if not math.isfinite(x):
            raise UsageError(f"{name} must be a finite number, got {x}")
    if tf <= coast:
        raise UsageError(f"--tf {tf:g} s must exceed the coast of {coast:g} s")
    if tf > MAX_TF:
        raise UsageError(f"--tf {tf:g} s is too long: move times up to {MAX_TF:g} s are planned")
    steps = _pick(args, cfg, "steps")
    if steps is not None:
        steps = _number(steps, "--steps", int)
        if steps < 0:
            raise UsageError(f"--steps must be >= 1 (or 0: chosen by the planner), got {steps}")
    if tol <= 0:
        raise UsageError(f"--tol must be > 0, got {tol}")
    objective = str(_pick(args, cfg, "objective"))
    if objective not in OBJECTIVES:
        raise UsageError(f"unknown objective {objective!r}; use one of {', '.join(OBJECTIVES)}")
    unc = _pick(args, cfg, "uncertain")
    named = _names(unc if isinstance(unc, (list, tuple)) else [unc]) if unc is not None else None
    uncertain = named if named is not None else list(params.friction_keys)
    box = _box(_pick(args, cfg, "box"))
    coast_max = _number(_pick(args, cfg, "coast_max"), "--coast-max")
    quantum = _number(_pick(args, cfg, "current_quantum"), "--current-quantum")
    if not (math.isfinite(quantum) and 0.0 <= quantum < 1.0):
        raise UsageError(f"--current-quantum must be a number in [0, 1) A (0 = none), got {quantum}")
    limits = MotionLimits.of(*(vec(k, []) or None for k in ("q_min", "q_max", "qd_max")))
    try:
        limits.validate(nj, q0, qf)
    except PlanningError as exc:
        raise UsageError(_flag_names(str(exc))) from None
    return PlanRequest(model=model, q0=tuple(q0), qf=tuple(qf), tf=tf, box=box,
                       limits=None if limits.empty else limits, tolerance=tolerance,
                       move_time_max=tf_max if tolerance is not None else None,
                       coast_max=coast_max, current_quantum=quantum,
                       uncertain=tuple(uncertain), objective=objective, steps=steps,
                       starts=_number(_pick(args, cfg, "starts"), "--starts", int),
                       seed=_number(_pick(args, cfg, "seed"), "--seed", int),
                       time_budget=time_budget, coast=coast, params=params, tol=tol)


def drive_of(args: argparse.Namespace):
    """The DriveGrid of ``--drive-config`` (or the plan file's ``plan: drive_config``), or None;
    UsageError naming the problem."""
    from ff_planner.optimize.drive_grid import DriveConfigError, drive_grid_from_config

    path = getattr(args, "drive_config", None)
    if path is None and getattr(args, "config", None):
        path = (load_config(args.config).get("plan") or {}).get("drive_config")
    if path is None or str(path) == "":
        return None
    try:
        return drive_grid_from_config(str(path))
    except DriveConfigError as exc:
        raise UsageError(f"--drive-config: {exc}") from None


def _flag_names(text: str) -> str:
    """A MotionLimits message in the flags' names."""
    for field_name, flag in (("position_min", "--q-min"), ("position_max", "--q-max"),
                             ("velocity_max", "--qd-max")):
        text = text.replace(field_name, flag)
    return text


def _tolerance(args: argparse.Namespace, cfg: dict) -> tuple[Optional[float], float]:
    """(tolerance rad or None, tf_max s) of a request; UsageError for bad values or --tf with
    --tolerance."""
    tol = _pick(args, cfg, "tolerance")
    tf_max_given = _pick(args, cfg, "tf_max")
    tf_max = DEFAULT_TF_MAX if tf_max_given is None else _number(tf_max_given, "--tf-max")
    if tol is None:
        if tf_max_given is not None and not getattr(args, "tradeoff", None):
            raise UsageError("--tf-max bounds a --tolerance search; give --tolerance too (or --tf)")
        return None, tf_max
    tolerance = _number(tol, "--tolerance")
    if not tolerance > 0.0:
        raise UsageError(f"--tolerance must be > 0 rad, got {tolerance:g}")
    if getattr(args, "tf", None) is not None or "tf" in (cfg.get("task") or {}):
        raise UsageError("give --tf or --tolerance, not both: with --tolerance the planner chooses "
                         "tf (bound it with --tf-max)")
    if not 0.0 < tf_max <= MAX_TF:
        raise UsageError(f"--tf-max must be in (0, {MAX_TF:g}] s, got {tf_max:g}")
    return tolerance, tf_max


def summary(result, output: Optional[str] = None, plot: Optional[str] = None) -> dict:
    """A short JSON-able summary of a PlanResult."""
    d = {
        "objective": result.objective, "success": bool(result.success),
        "robust": bool(result.robust), "best_effort": bool(result.best_effort),
        "error_code": result.error_code, "message": result.message,
        "q_final": np.asarray(result.q_final).tolist(),
        "qd_final": np.asarray(result.qd_final).tolist(),
        "sensitivities": {k: float(v) for k, v in result.sensitivities.items()},
        "steps": None if result.profile is None else result.profile.n_steps,
        "starts_tried": int(result.starts_tried), "solve_time_s": float(result.solve_time),
    }
    rest = (result.extra or {}).get("rest_position")
    if rest is not None:
        d["rest_position"] = np.asarray(rest, dtype=float).tolist()
    cert = getattr(result, "certificate", None)
    if cert is not None:
        d["certificate"] = cert.to_dict()
    for key in ("limits_checked", "limit_violations", "tolerance_search", "drive_exact"):
        if key in (result.extra or {}):
            d[key] = result.extra[key]
    if output:
        d["output"] = output
    if plot:
        d["plot"] = plot
    return d


def _print_summary(d: dict, result) -> None:
    state = ("BEST-EFFORT plan (leaves the limits)" if d.get("limit_violations")
             else "robust plan" if d["robust"] and d["success"]
             else "plan (meets the goal)" if d["success"]
             else f"NO PLAN [{d['error_code']}]" if result.profile is None
             else "BEST-EFFORT plan (does not meet the tolerances)")
    print(f"{PROG}: {d['objective']}: {state} — {d['message']}")
    if result.profile is None:
        print(f"  starts: {d['starts_tried']}, time: {d['solve_time_s'] * 1e3:.1f} ms")
        return
    if result.profile is not None:
        cur = np.round(result.profile.currents, 4).tolist()
        print(f"  steps: {d['steps']}, currents (A): {cur}")
    print(f"  q(tf) = {np.round(d['q_final'], 9).tolist()} rad, "
          f"qd(tf) = {np.round(d['qd_final'], 9).tolist()} rad/s"
          + (f", rest at {np.round(d['rest_position'], 9).tolist()} rad"
             if "rest_position" in d else ""))
    sens = {k: v for k, v in d["sensitivities"].items() if not k.startswith("qd")}
    if len(sens) > 6:
        k_max = max(sens, key=lambda k: abs(sens[k]))
        print(f"  dq(tf)/dp: max |{k_max}| = {abs(sens[k_max]):.2e} over {len(sens)} values "
              f"(all in the motion file)")
    elif sens:
        print("  dq(tf)/dp: " + ", ".join(f"{k} {v:+.2e}" for k, v in sens.items()))
    c = d.get("certificate")
    if c:
        box = ", ".join(f"{k} ±{v * 100:g} %" for k, v in c["box"].items())
        at = ", ".join(f"{k}×{v:.3g}" for k, v in c["worst_at"].items())
        alone = ", ".join(f"{k} {v * 1e3:.3g}" for k, v in c["per_parameter"].items())
        sw = max((abs(x) for x in c["switch_timing_per_100us"]), default=0.0)
        print(f"  box ({box}): worst rest error {c['worst_rest_error'] * 1e3:.3g} mrad at {at}; "
              f"alone (mrad): {alone}; moving at tf: {c['moving_at_tf'] * 100:.0f} % of the box; "
              f"switch timing: max {sw * 1e3:.3g} mrad per 100 us delay")
        _print_excursion(c.get("excursion"), getattr(result, "extra", None) or {})
    _print_drive(d.get("drive_exact"), c)
    search = (getattr(result, "extra", None) or {}).get("tolerance_search")
    if search:
        _print_search(search)
    print(f"  starts: {d['starts_tried']}, time: {d['solve_time_s'] * 1e3:.1f} ms")
    for k in ("output", "plot"):
        if k in d:
            print(f"  wrote {d[k]}")


def _fmt(values, scale: float = 1.0) -> str:
    return "[" + ", ".join("-" if v is None or not math.isfinite(float(v)) else f"{float(v) * scale:.4g}"
                           for v in values) + "]"


def _print_excursion(ex: Optional[dict], extra: dict) -> None:
    """Where the plan takes the arm until rest: nominal and the worst over the box's points."""
    if not ex:
        return
    print(f"  excursion until rest (per joint): nominal {_fmt(ex['nominal_min'])} … "
          f"{_fmt(ex['nominal_max'])} rad, peak speed {_fmt(ex['nominal_speed'])} rad/s; over the "
          f"box {_fmt(ex['worst_min'])} … {_fmt(ex['worst_max'])} rad, peak speed "
          f"{_fmt(ex['worst_speed'])} rad/s")
    broken = extra.get("limit_violations")
    if broken:
        print(f"  LIMITS BROKEN over the box: {'; '.join(broken)}")
    elif "limits_checked" in extra:
        print("  within the limits over the box" if extra["limits_checked"]
              else "  limits NOT checked (no excursion)")


def _print_drive(info: Optional[dict], cert: Optional[dict]) -> None:
    """The drive-exact profile: its grid, what rounding moved, what the certificate is for."""
    if not info:
        return
    if info.get("error"):
        print(f"  drive-exact: NOT applied: {info['error']}")
        return
    period = float(info["switch_period_s"])
    grid = f"{period * 1e3:g} ms SYNC" if period > 0.0 else "no SYNC grid (on receipt)"
    shift = [f"{x * 1e3:+.3g}" for x in info.get("rest_shift_rad") or []]
    ref = info.get("refine") or {}
    print(f"  drive-exact: {float(info['current_quantum_A']) * 1e3:g} mA steps, {grid} "
          f"({info.get('source') or 'drive config'}); switches moved up to "
          f"{float(info.get('max_switch_shift_s', 0.0)) * 1e3:.3g} ms, nominal rest moved "
          f"{', '.join(shift) or '-'} mrad"
          + (f"; rounding refined: worst {ref['worst_before_rad'] * 1e3:.3g} -> "
             f"{ref['worst_after_rad'] * 1e3:.3g} mrad on the refinement's points" if ref else ""))
    if cert and cert.get("drive"):
        print("  certificate computed on the profile sent to the drive (currents on its quantum, "
              "switches on its SYNC grid)")


def _print_search(search: dict) -> None:
    """The tolerance search: every tf tried with its certified worst rest error and time."""
    print(f"  tolerance search ({search['tolerance'] * 1e3:.3g} mrad, tf <= "
          f"{search['move_time_max']:g} s): {len(search['trials'])} move times in "
          f"{search['time_s']:.1f} s{'' if search['complete'] else ' (stopped by the time budget)'}")
    seed0 = search["trials"][0].get("seed") if search["trials"] else None
    for t in search["trials"]:
        w = t["worst_rest_error"]
        what = "no certified plan" if w is None else f"certified {w * 1e3:.3g} mrad"
        again = "" if t.get("seed") == seed0 else f" (again, seed {t.get('seed')})"
        print(f"    tf {t['tf']:.3f} s{again}: {what}, {'meets' if t['meets'] else 'fails'} "
              f"({t['time_s']:.2f} s)" + ("" if t["meets"] or not t["note"] or w is not None
                                          else f": {t['note']}"))


def _tradeoff(args: argparse.Namespace, request: PlanRequest, progress, plan_fn=None) -> int:
    """--tradeoff: certified rest error and excursion against move time; table, JSON, PNG."""
    from ff_planner.optimize.fastest import tradeoff

    if not 2 <= int(args.tradeoff_points) <= 100:
        raise UsageError(f"--tradeoff-points must be in [2, 100], got {args.tradeoff_points}")
    given = request.move_time_max if request.tolerance is not None else getattr(args, "tf_max", None)
    tf_max = DEFAULT_TF_MAX if given is None else float(_number(given, "--tf-max"))
    if not 0.0 < tf_max <= MAX_TF:
        raise UsageError(f"--tf-max must be in (0, {MAX_TF:g}] s, got {tf_max:g}")
    kw = {} if plan_fn is None else {"plan_fn": plan_fn}
    pts = tradeoff(request, int(args.tradeoff_points), tf_max, progress=progress, **kw)
    _plot_tradeoff(pts, request, args.tradeoff)
    rows = [p.to_dict() for p in pts]
    if args.json:
        print(json.dumps(jsonable({"tradeoff": rows, "plot": args.tradeoff,
                                   "tolerance": request.tolerance,
                                   "limits": request.limits.to_dict() if request.limits else None}),
                         allow_nan=False))
        return 0
    print(f"{PROG}: trade-off, {np.round(request.q0, 4).tolist()} -> "
          f"{np.round(request.qf, 4).tolist()} rad, {request.objective}: certified worst rest error "
          f"over the box and the worst excursion until rest")
    for r in rows:
        w = r["worst_rest_error"]
        print(f"  {r['label']:>9}  tf {r['tf']:6.3f} s: "
              + ("no certified plan" if w is None else f"{w * 1e3:9.3g} mrad")
              + ("" if r["success"] else f" [{r['error_code']}]")
              + (f"; position {_fmt(r['worst_min'])} … {_fmt(r['worst_max'])} rad, speed "
                 f"{_fmt(r['worst_speed'])} rad/s" if r["worst_speed"] else ""))
    print(f"  wrote {args.tradeoff}")
    return 0


def _plot_tradeoff(pts, request: PlanRequest, path: str) -> None:
    """Two panels: certified worst rest error (mrad, log) and worst peak speed (rad/s) against tf;
    one line per set of limits, hollow markers where the plan is not a success."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 4.2))
    FigureCanvasAgg(fig)
    ax_err, ax_speed = fig.subplots(1, 2)
    for label in dict.fromkeys(p.label for p in pts):
        rows = [p for p in pts if p.label == label and p.worst_rest_error is not None
                and math.isfinite(p.worst_rest_error)]
        if not rows:
            continue
        tf = [p.tf for p in rows]
        line, = ax_err.plot(tf, [p.worst_rest_error * 1e3 for p in rows], "-", label=label)
        for p in rows:
            ax_err.plot(p.tf, p.worst_rest_error * 1e3, "o", color=line.get_color(),
                        fillstyle="full" if p.success else "none")
        sp = [(p.tf, max(p.worst_speed)) for p in rows if p.worst_speed]
        if sp:
            ax_speed.plot(*zip(*sp), "o-", color=line.get_color(), label=label)
    if request.tolerance is not None:
        ax_err.axhline(request.tolerance * 1e3, color="k", ls="--", lw=0.8, label="tolerance")
    lim = request.limits
    if lim is not None and lim.velocity_max:
        ax_speed.axhline(max(lim.velocity_max), color="k", ls="--", lw=0.8, label="velocity_max")
    ax_err.set_yscale("log")
    ax_err.set_xlabel("move time tf (s)")
    ax_err.set_ylabel("certified worst rest error (mrad)")
    ax_err.set_title("rest error over the friction box (hollow: not a success)", fontsize=9)
    ax_speed.set_xlabel("move time tf (s)")
    ax_speed.set_ylabel("worst peak speed over the box (rad/s)")
    for ax in (ax_err, ax_speed):
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split())


def _check_writable(path: Optional[str], flag: str) -> None:
    if path is None:
        return
    parent = Path(path).resolve().parent
    if not parent.is_dir():
        raise UsageError(f"{flag}: folder {str(parent)!r} does not exist")


def _protect_numbers(argv: Sequence[str]) -> list[str]:
    """Values such as ``-inf``, ``-nan`` or ``-1e3`` that argparse would take for options: give
    them a leading space (``float`` ignores it), so that they reach the value checks."""
    out = []
    for a in argv:
        if a.startswith("-") and not a.startswith("--"):
            try:
                float(a)
                a = " " + a
            except ValueError:
                pass
        out.append(a)
    return out


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point of ``ff-plan``; returns the exit code (see module docstring)."""
    raw = list(sys.argv[1:] if argv is None else argv)
    if any(a == opt or a.startswith(opt + "=") for a in raw for opt in ("--urdf", "--cell")):
        from ff_planner.cli import plan_urdf     # an arm from a URDF + cell file (docs/arms.md)

        return plan_urdf.main(raw)
    parser = build_parser()
    debug = "--debug" in raw
    try:
        args = parser.parse_args(_protect_numbers(raw))
        _check_writable(args.output, "-o")
        _check_writable(args.plot, "--plot")
        _check_writable(getattr(args, "tradeoff", None), "--tradeoff")
        request = make_request(args)
        drive = drive_of(args)
        # after argument checks: keeps --help and errors fast
        from ff_planner.optimize.fastest import plan_fastest
        from ff_planner.optimize.planner import on_drive_grid, plan

        progress = None if args.quiet else ProgressPrinter()
        plan_fn = plan if drive is None else functools.partial(plan, drive=drive)
        request = on_drive_grid(request, drive)   # a search's move times on the SYNC grid too
        if getattr(args, "tradeoff", None):
            return _tradeoff(args, request, progress, plan_fn)
        result = (plan_fastest(request, progress, plan_fn=plan_fn) if request.tolerance is not None
                  else plan_fn(request, progress))
        if args.output and result.profile is not None:
            from ff_planner.export.motion_file import write_motion

            write_motion(args.output, result)
        if args.plot and result.profile is not None:
            from ff_planner.export.plotting import plot_motion

            plot_motion(result.params or request.resolved_params(), result.profile, np.asarray(result.q0).tolist(),
                        np.asarray(result.qf).tolist(), result.uncertain,
                        args.plot, title=f"{result.objective}: {result.model}, "
                                         f"{np.round(result.q0, 4).tolist()} → {np.round(result.qf, 4).tolist()} rad "
                                         f"in {result.profile.tf:g} s")
        d = summary(result, args.output if result.profile is not None else None,
                    args.plot if result.profile is not None else None)
        if args.json:
            print(json.dumps(jsonable(d), allow_nan=False))
        else:
            _print_summary(d, result)
        return 0 if result.success else 1
    except SystemExit as e:   # --help / --version
        return int(e.code or 0)
    except (UsageError, PlanningError, ParameterError) as e:
        code = getattr(e, "code", None)
        tag = f" [{code}]" if code and code not in ("INVALID_REQUEST",) else ""
        print(f"{PROG}: error{tag}: {_one_line(e)}", file=sys.stderr)
        return 2
    except ValueError as e:   # other clear library errors (e.g. motion file)
        print(f"{PROG}: error: {_one_line(e)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # never a traceback for the user unless asked
        if debug:
            raise
        print(f"{PROG}: internal error: {type(e).__name__}: {e} (rerun with --debug)",
              file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())

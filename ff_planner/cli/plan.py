"""``ff-plan``: plan a robust (or baseline) feedforward move from the command line.

Writes an ff-motion/1 file (``-o``), optionally a Fig. 5/7-style PNG (``--plot``), and prints a
short summary. Exit codes: 0 plan found and meets its tolerances; 1 only a best-effort plan
(written, labelled) or an internal error; 2 bad input or unreachable goal (one error line).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import NoReturn, Optional, Sequence

import numpy as np

from ff_planner.model.params import DEFAULT_PRESET, MODELS, PRESETS, ParameterError, load_params, n_joints, preset
from ff_planner.model.profile import DEFAULT_COAST, DEFAULT_COAST_MAX, MAX_TF, OBJECTIVES, PlanningError, PlanRequest

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


def build_parser() -> argparse.ArgumentParser:
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
                   help="plan file: model/preset/params plus task: {q0, qf, tf, coast} and "
                        "plan: {uncertain, objective, steps, starts, seed, time_budget, tol}; "
                        "command-line flags override it (examples in config/plan_*.yaml)")
    m.add_argument("--set", metavar="KEY=VALUE", action="append", default=[],
                   help="override one model parameter, e.g. --set pc=0.22 (repeatable)")
    t = p.add_argument_group("task")
    t.add_argument("--q0", nargs="+", default=None, metavar="RAD",
                   help="start position per joint (default 0, or -0.5 0 for scara2)")
    t.add_argument("--qf", nargs="+", default=None, metavar="RAD",
                   help="goal position per joint (default 1, or 0.5 0 for scara2)")
    t.add_argument("--tf", type=float, default=None, metavar="S", help="move time (default 1 s)")
    t.add_argument("--coast", type=float, default=None, metavar="S",
                   help=f"zero-current coast at the end (default {DEFAULT_COAST} s)")
    o = p.add_argument_group("optimisation")
    o.add_argument("--uncertain", nargs="+", default=None, metavar="NAME",
                   help="friction parameters to be robust to (default: all of the model's)")
    o.add_argument("--objective", choices=OBJECTIVES, default=None,
                   help="robust-box (default: least worst rest error over the friction box, "
                        "among plans with zero exact derivatives), robust-derivative (the paper's "
                        "zero derivatives alone), robust-sampled, time-optimal, energy-optimal")
    o.add_argument("--steps", type=int, default=None, metavar="N",
                   help="current steps per joint (default: robust-box 8, raised to 10, 12 while "
                        "no truly robust plan is found; others 2 + number of uncertain "
                        "parameters; 0: the robust 1-DOF planner chooses the smallest N up to 12, "
                        "robust-box until the box worst is <= 5 mrad)")
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
    o.add_argument("--time-budget", type=float, default=None, metavar="S",
                   help="wall-clock budget (default 30 s); the best plan so far is returned")
    o.add_argument("--tol", type=float, default=None,
                   help="robustness tolerance on |dq(tf)/dp| and |q(tf)-qf| (default 1e-6)")
    out = p.add_argument_group("output")
    out.add_argument("-o", "--output", metavar="JSON", default=None, help="write the motion file")
    out.add_argument("--plot", metavar="PNG", default=None,
                     help="write a figure: current, position at nominal and ±40 %% friction, "
                          "final position vs parameter change")
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
_TASK_KEYS = ("q0", "qf", "tf", "coast")
_PLAN_KEYS = ("uncertain", "objective", "steps", "starts", "seed", "time_budget", "tol", "box",
              "coast_max", "current_quantum")


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
    v = getattr(args, key)
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
        return _floats([str(x) for x in (v if isinstance(v, (list, tuple)) else [v])], f"--{key}")

    q0 = vec("q0", [0.0] if nj == 1 else [-0.5, 0.0])
    qf = vec("qf", [1.0] if nj == 1 else [0.5, 0.0])
    for name, v in (("--q0", q0), ("--qf", qf)):
        if len(v) != nj:
            raise UsageError(f"{name} needs {nj} value(s) for model '{model}', got {len(v)}")
    tf = _number(_pick(args, cfg, "tf"), "--tf")
    coast = _number(_pick(args, cfg, "coast"), "--coast")
    time_budget = _number(_pick(args, cfg, "time_budget"), "--time-budget")
    tol = _number(_pick(args, cfg, "tol"), "--tol")
    for name, v in (("--tf", tf), ("--coast", coast), ("--time-budget", time_budget),
                    ("--tol", tol)):
        if not math.isfinite(v):
            raise UsageError(f"{name} must be a finite number, got {v}")
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
    return PlanRequest(model=model, q0=tuple(q0), qf=tuple(qf), tf=tf, box=box,
                       coast_max=coast_max, current_quantum=quantum,
                       uncertain=tuple(uncertain), objective=objective, steps=steps,
                       starts=_number(_pick(args, cfg, "starts"), "--starts", int),
                       seed=_number(_pick(args, cfg, "seed"), "--seed", int),
                       time_budget=time_budget, coast=coast, params=params, tol=tol)


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
    if output:
        d["output"] = output
    if plot:
        d["plot"] = plot
    return d


def _print_summary(d: dict, result) -> None:
    state = ("robust plan" if d["robust"] else "plan (meets the goal)" if d["success"]
             else "BEST-EFFORT plan (does not meet the tolerances)")
    print(f"{PROG}: {d['objective']}: {state} — {d['message']}")
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
    print(f"  starts: {d['starts_tried']}, time: {d['solve_time_s'] * 1e3:.1f} ms")
    for k in ("output", "plot"):
        if k in d:
            print(f"  wrote {d[k]}")


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
    parser = build_parser()
    raw = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in raw
    try:
        args = parser.parse_args(_protect_numbers(raw))
        _check_writable(args.output, "-o")
        _check_writable(args.plot, "--plot")
        request = make_request(args)
        from ff_planner.optimize.planner import plan  # after argument checks: keeps --help and errors fast

        result = plan(request, None if args.quiet else ProgressPrinter())
        if args.output and result.profile is not None:
            from ff_planner.export.motion_file import write_motion

            write_motion(args.output, result)
        if args.plot and result.profile is not None:
            from ff_planner.export.plotting import plot_motion

            plot_motion(result.params or request.resolved_params(), result.profile, np.asarray(result.q0).tolist(),
                        np.asarray(result.qf).tolist(), result.uncertain,
                        args.plot, title=f"{result.objective}: {result.model}, "
                                         f"{np.round(result.q0, 4).tolist()} → {np.round(result.qf, 4).tolist()} rad "
                                         f"in {request.tf:g} s")
        d = summary(result, args.output if result.profile is not None else None,
                    args.plot if result.profile is not None else None)
        if args.json:
            print(json.dumps(d))
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

"""``ff-identify``: identify the 1-DOF arm's friction (Eq. 9: pv, pc, pt; J optionally) from its motions.

    ff-identify --records runs.json -o params.yaml --report rep/     # fit recorded runs
    ff-identify --simulate --sim-set pc=0.25 --json                  # simulated measurement, no ROS
    ff-identify --sim --sim-set pc=0.25 -o params.yaml               # on the simulated ROS stack
    ff-identify --update params.yaml --executions runs.json -o updated.yaml --json   # learn from use

``--sim`` starts the simulated stack with those true parameters, runs the excitation through the
executor action and records the drive's encoder answers off the CAN bus, each at the SYNC it
answered (``ff_executor.bringup.identify``, the
runner the ``ff-identify`` console script hands in; this module loads no ROS, so the offline modes
run anywhere). Exit codes: 0 the friction law fits the runs; 1 it does not (model mismatch:
outputs are written, labelled) or the run failed; 2 bad input (one error line).

``--update`` learns from use (``ff_planner.identify.learn``): the parameter file's estimate and
covariance are the prior, each logged execution's measured rest position the evidence; exit code
1 when the rest positions disagree with the updated estimate and their noise.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Callable, Mapping, NoReturn, Optional, Sequence

import numpy as np

from ff_planner.identify.excitation import Envelope, design_excitation
from ff_planner.export.motion_file import read_motion, validate_motion_dict
from ff_planner.identify.fit import fit_friction
from ff_planner.identify.learn import (
                                       DEFAULT_Q_SIGMA,
                                       load_executions,
                                       load_prior,
                                       profile_from_record,
                                       update_from_executions,
                                       update_summary,
)
from ff_planner.identify.measure import FrictionMismatch, Sensors, measure_runs
from ff_planner.identify.output import plan_config_yaml, summary, update_report_text, write_params, write_report
from ff_planner.identify.records import RunRecord, load_records, save_records
from ff_planner.model.params import Arm1DofParams, ParameterError, load_params, preset
from ff_planner.model.profile import CurrentProfile

PROG = "ff-identify"

#: runs the excitation on the ROS stack: (excitation, base params, true params, q_start, log,
#: measure=..., friction=...) -> (records, meta); supplied by ``ff_executor.bringup.identify``
SimRunner = Callable[..., tuple[list[RunRecord], dict]]


class UsageError(Exception):
    """Bad command-line input (exit code 2)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        raise UsageError(f"{message} (see {PROG} --help)")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description=__doc__.splitlines()[0].split(": ", 1)[1],
                formatter_class=argparse.RawDescriptionHelpFormatter,
                epilog="\n".join(__doc__.splitlines()[2:5]))
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--records", metavar="JSON", help="fit the runs of an ff-identify-records/1 file")
    src.add_argument("--sim", action="store_true", help="run the excitation on the simulated ROS stack")
    src.add_argument("--simulate", action="store_true",
                     help="run it on the exact model with a simulated encoder and current sensor (no ROS)")
    src.add_argument("--update", metavar="YAML",
                     help="learn from use: update this ff-identify parameter file from --executions")
    u = p.add_argument_group("learning from use (--update)")
    u.add_argument("--executions", action="append", nargs="+", default=[], metavar="JSON",
                   help="logged executions: a JSON list of {motion: ff-motion/1 path or inline profile, "
                        "rest_position: rad [, q_sigma: rad] [, q0: rad]}")
    u.add_argument("--q-sigma", type=float, default=DEFAULT_Q_SIGMA, metavar="RAD",
                   help=f"rest position noise of executions that do not state one (default {DEFAULT_Q_SIGMA:g})")
    u.add_argument("--drift", type=float, default=0.0, metavar="FRACTION",
                   help="how much the friction may have changed since the parameter file was written "
                        "(1 sigma, fraction of each value; adds to the prior's variance; default 0)")
    u.add_argument("--prior-box", action="append", default=[], metavar="KEY=FRACTION", type=_key_value,
                   help="the prior as a 95 %% box estimate*(1 +- b) per pv, pc, pt, for a parameter file "
                        "without ff-identify's covariance or intervals")
    p.add_argument("--sim-set", action="append", default=[], metavar="KEY=VALUE", type=_key_value,
                   help="a true parameter of the simulated arm (SI), e.g. pc=0.25 (--sim, --simulate)")
    p.add_argument("--sim-friction", action="append", default=[], metavar="KEY=VALUE", type=_key_value,
                   help="--simulate: friction that is not Eq. 9, to test the fit's honesty: stribeck=F "
                        "(extra static friction, fraction of pc), stribeck_speed=RAD/S (default 0.1), "
                        "coulomb_ripple=F (Coulomb level varying with position), coulomb_period=RAD "
                        "(default 0.25)")
    p.add_argument("--sim-measure", choices=("joints", "truth"), default="joints",
                   help="--sim records: the drive's encoder (its TPDO answers read off the CAN bus, each at "
                        "the SYNC it answered; default) or the simulated arm's ground truth rounded to the "
                        "encoder (exact sample times)")
    p.add_argument("--params", metavar="YAML", default=None,
                   help="the guess: load_params YAML (default table 2); J, kt, n, i_max stay as given")
    p.add_argument("--fit-inertia", action="store_true", help="fit J too")
    p.add_argument("--q-noise", type=float, default=0.0, metavar="RAD",
                   help="position noise rms besides the encoder quantum, for the chi2 test (e.g. sample "
                        "time jitter x speed)")
    e = p.add_argument_group("excitation envelope (--sim, --simulate)")
    e.add_argument("--q-min", type=float, default=-1.0, metavar="RAD")
    e.add_argument("--q-max", type=float, default=1.0, metavar="RAD")
    e.add_argument("--v-max", type=float, default=3.0, metavar="RAD/S")
    e.add_argument("--i-max", type=float, default=None, metavar="A",
                   help="default: the model's limit (--sim: 3 A, the stack's excitation)")
    e.add_argument("--q-start", type=float, default=0.0, metavar="RAD", help="where the arm rests (--simulate)")
    e.add_argument("--levels", type=int, default=4, help="current levels (each run in both directions)")
    e.add_argument("--min-step", type=float, default=0.02, metavar="S",
                   help="shortest drive phase (longer phases are less sensitive to switch timing)")
    e.add_argument("--timing-margin", type=float, default=None, metavar="S",
                   help="the envelope must hold with a switch this late (default 0; --sim: 0.02, a busy host)")
    e.add_argument("--spread", type=float, default=0.5,
                   help="prior box of the guess, relative (the envelope must hold for all of it)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (--simulate)")
    o = p.add_argument_group("output")
    o.add_argument("-o", "--output", metavar="YAML", help="write the parameter file (ff-plan --params)")
    o.add_argument("--plan-config", metavar="YAML",
                   help="write an ff-plan --config file: these parameters + plan.box (the uncertainty box)")
    o.add_argument("--report", metavar="DIR", help="write report.txt and fit.png")
    o.add_argument("--save-records", metavar="JSON", help="write the measured runs (--sim, --simulate)")
    o.add_argument("--box-floor", type=float, default=0.02,
                   help="smallest uncertainty box fraction written (default 0.02)")
    o.add_argument("--json", action="store_true", help="print the summary as JSON")
    return p


def _key_value(item: str) -> tuple[str, float]:
    """argparse type of ``--sim-set``: "pc=0.25" -> ("pc", 0.25)."""
    key, sep, value = item.partition("=")
    try:
        if not sep:
            raise ValueError
        return key.strip(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"needs KEY=VALUE with a number, got {item!r}") from None


def _mismatch(items: Sequence[tuple[str, float]]) -> FrictionMismatch:
    bad = [k for k, _ in items if k not in FrictionMismatch.KEYS]
    if bad:
        raise UsageError(f"--sim-friction: unknown key(s) {bad}; use {', '.join(FrictionMismatch.KEYS)}")
    m = FrictionMismatch(**dict(items))
    m.validate()
    return m


def _guess(path: Optional[str]) -> Arm1DofParams:
    if path is None:
        p = preset("table2")
    else:
        if not Path(path).is_file():
            raise UsageError(f"--params: no such file {path!r}")
        p = load_params(path)
    if not isinstance(p, Arm1DofParams):
        raise UsageError(f"identification supports model 'arm1dof' only, got '{p.model}'")
    return p


def run(args: argparse.Namespace, sim_runner: Optional[SimRunner] = None,
        log: Callable[[str], None] = lambda s: print(s, file=sys.stderr, flush=True)) -> tuple[int, dict[str, Any]]:
    """Do what the arguments ask; returns (exit code, summary)."""
    if args.update:
        return _update(args)
    if args.executions:
        raise UsageError("--executions needs --update PARAMS.yaml")
    meta: dict[str, Any] = {}
    truth: Optional[dict] = None
    if args.records:
        if not Path(args.records).is_file():
            raise UsageError(f"--records: no such file {args.records!r}")
        records, base, meta = load_records(args.records)
        if args.params:
            base = _guess(args.params)
        truth = meta.get("truth")
        source = args.records
    else:
        if args.sim and sim_runner is None:
            raise UsageError("--sim needs the on-stack runner: use the ff-identify console script "
                             "(python -m ff_executor.bringup.identify)")
        mismatch = _mismatch(args.sim_friction) if args.sim_friction else None
        base = _guess(args.params)
        true_vals = dict(args.sim_set)
        true = base.replace(**true_vals)
        i_max = args.i_max if args.i_max is not None else (3.0 if args.sim else None)
        margin = args.timing_margin if args.timing_margin is not None else (0.02 if args.sim else 0.0)
        env = Envelope(args.q_min, args.q_max, args.v_max, i_max)
        ex = design_excitation(base, env, args.q_start, n_levels=args.levels, spread=args.spread,
                                min_step=args.min_step, timing_margin=margin)
        log(f"{PROG}: {len(ex.runs)} runs at {sorted({round(r.level, 3) for r in ex.runs})} A, "
            f"{ex.duration:.1f} s of motion")
        if args.sim and sim_runner is not None:
            records, meta = sim_runner(ex, base, true_vals, args.q_start, log, measure=args.sim_measure,
                                       friction=dict(args.sim_friction) if mismatch is not None else None)
            source = "the simulated stack"
        else:
            records = measure_runs(true, ex.profiles, args.q_start, Sensors(), np.random.default_rng(args.seed),
                                   mismatch=mismatch)
            source = "a simulated measurement" + (" with friction that is not Eq. 9" if mismatch else "")
        truth = true.to_dict()
        meta["truth"] = truth
        if mismatch is not None:
            meta["friction_mismatch"] = dict(args.sim_friction)
        if args.save_records:
            save_records(args.save_records, records, base, meta)
    fit = fit_friction(records, base, fit_inertia=args.fit_inertia, q_noise=args.q_noise)
    out = summary(fit, args.box_floor, {"source": source})
    if truth:
        out["truth"] = {k: float(truth[k]) for k in fit.keys if k in truth}
    if args.output:
        write_params(args.output, fit, args.box_floor, source)
    if args.plan_config:
        Path(args.plan_config).write_text(plan_config_yaml(fit, args.box_floor))
    if args.report:
        write_report(fit, args.report, truth, args.box_floor)
    return (0 if fit.adequate else 1), out


def _load_motion(motion: str | Mapping[str, Any], folder: Path) -> tuple[CurrentProfile, Optional[float]]:
    """An executed motion: an ff-motion/1 file (path relative to the executions file), an inline
    ff-motion/1 object or an inline CurrentProfile-like record; (profile, planned q0 rad)."""
    if isinstance(motion, str):
        path = Path(motion) if Path(motion).is_absolute() else folder / motion
        m = read_motion(path)
    elif "format" in motion:
        m = validate_motion_dict(motion)
    else:
        return profile_from_record(motion)
    if m.model != "arm1dof":
        raise ParameterError(f"learning from use supports model 'arm1dof' only, got '{m.model}'")
    return m.profile, float(m.q0[0])


def _update(args: argparse.Namespace) -> tuple[int, dict[str, Any]]:
    """--update: the parameter file as the prior, the executions' rest positions as evidence."""
    if not Path(args.update).is_file():
        raise UsageError(f"--update: no such file {args.update!r}")
    files = [f for group in args.executions for f in group]
    if not files:
        raise UsageError("--update needs --executions JSON (the logged executions)")
    if not (args.q_sigma > 0.0):
        raise UsageError(f"--q-sigma must be > 0 rad, got {args.q_sigma}")
    for f in files:
        if not Path(f).is_file():
            raise UsageError(f"--executions: no such file {f!r}")
    prior = load_prior(args.update, dict(args.prior_box) if args.prior_box else None).with_drift(args.drift)
    executions = [e for f in files for e in load_executions(f, _load_motion, args.q_sigma)]
    res = update_from_executions(prior, executions)
    out = update_summary(res, args.box_floor, {"source": args.update, "executions_files": files})
    src = f"{args.update} updated from {len(executions)} execution(s)"
    if args.output:
        write_params(args.output, res, args.box_floor, src)
    if args.plan_config:
        Path(args.plan_config).write_text(plan_config_yaml(res, args.box_floor))
    if args.report:
        d = Path(args.report)
        d.mkdir(parents=True, exist_ok=True)
        (d / "update.txt").write_text(update_report_text(res, args.box_floor))
    return (0 if res.adequate else 1), out


def _print_human(out: dict[str, Any]) -> None:
    print(f"{PROG}: {out['message']}")
    for k, v in out["estimates"].items():
        lo, hi = out["interval95"][k]
        print(f"  {k:<3} = {v:.6g} {out['units'][k]}   95 % [{lo:.6g}, {hi:.6g}]"
              + (f"   box ±{100 * out['box'][k]:.2f} %" if k in out["box"] else ""))
    if "executions" in out:
        for e in out["executions"]:
            print(f"  {e['name']}: {e['information_bits']:.2f} bits, rest error before "
                  f"{1e3 * (e['measured_rest_rad'] - e['predicted_rest_prior_rad']):+.3f} mrad, after "
                  f"{1e3 * (e['measured_rest_rad'] - e['predicted_rest_posterior_rad']):+.3f} mrad")
        return
    print(f"  {out['n_runs']} runs, {out['motion_seconds']:.1f} s of motion, residual rms {out['rms_rad']:.3g} rad")


def main(argv: Optional[Sequence[str]] = None, sim_runner: Optional[SimRunner] = None) -> int:
    """Console entry (see the module docstring); ``sim_runner`` serves ``--sim``."""
    try:
        args = build_parser().parse_args(argv)
        code, out = run(args, sim_runner)
    except UsageError as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2
    except (ParameterError, ValueError) as exc:
        print(f"{PROG}: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    except RuntimeError as exc:      # the stack failed (BringupError, StackCallError, refusals)
        print(f"{PROG}: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        _print_human(out)
    return code


if __name__ == "__main__":
    sys.exit(main())

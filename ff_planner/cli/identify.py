"""``ff-identify``: identify the 1-DOF arm's friction (Eq. 9: pv, pc, pt; J optionally) from its motions.

    ff-identify --records runs.json -o params.yaml --report rep/     # fit recorded runs
    ff-identify --simulate --sim-set pc=0.25 --json                  # simulated measurement, no ROS
    ff-identify --sim --sim-set pc=0.25 -o params.yaml               # on the simulated ROS stack

``--sim`` starts the simulated stack with those true parameters, runs the excitation through the
executor action and records the bridge's joint states (``ff_executor.bringup.identify``, the
runner the ``ff-identify`` console script hands in; this module loads no ROS, so the offline modes
run anywhere). Exit codes: 0 the friction law fits the runs; 1 it does not (model mismatch:
outputs are written, labelled) or the run failed; 2 bad input (one error line).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Callable, NoReturn, Optional, Sequence

import numpy as np

from ff_planner.identify.excitation import Envelope, design_excitation
from ff_planner.identify.fit import fit_friction
from ff_planner.identify.measure import Sensors, measure_runs
from ff_planner.identify.output import plan_config_yaml, summary, write_params, write_report
from ff_planner.identify.records import RunRecord, load_records, save_records
from ff_planner.model.params import Arm1DofParams, ParameterError, load_params, preset

PROG = "ff-identify"

#: runs the excitation on the ROS stack: (excitation, base params, true params, q_start, log,
#: measure=...) -> (records, meta); supplied by ``ff_executor.bringup.identify``
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
    p.add_argument("--sim-set", action="append", default=[], metavar="KEY=VALUE", type=_key_value,
                   help="a true parameter of the simulated arm (SI), e.g. pc=0.25 (--sim, --simulate)")
    p.add_argument("--sim-measure", choices=("joints", "truth"), default="joints",
                   help="--sim records: the bridge's joint states (default) or the simulated arm's ground "
                        "truth rounded to the encoder (exact sample times)")
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
    e.add_argument("--i-max", type=float, default=None, metavar="A", help="default: the model's limit")
    e.add_argument("--q-start", type=float, default=0.0, metavar="RAD", help="where the arm rests (--simulate)")
    e.add_argument("--levels", type=int, default=4, help="current levels (each run in both directions)")
    e.add_argument("--min-step", type=float, default=0.02, metavar="S",
                   help="shortest drive phase (longer phases are less sensitive to switch timing)")
    e.add_argument("--timing-margin", type=float, default=0.0, metavar="S",
                   help="the envelope must hold with a switch this late, e.g. 0.02 with --sim --i-max 3 "
                        "on a busy host (default 0)")
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
        base = _guess(args.params)
        true_vals = dict(args.sim_set)
        true = base.replace(**true_vals)
        env = Envelope(args.q_min, args.q_max, args.v_max, args.i_max)
        ex = design_excitation(base, env, args.q_start, n_levels=args.levels, spread=args.spread,
                                min_step=args.min_step, timing_margin=args.timing_margin)
        log(f"{PROG}: {len(ex.runs)} runs at {sorted({round(r.level, 3) for r in ex.runs})} A, "
            f"{ex.duration:.1f} s of motion")
        if args.sim and sim_runner is not None:
            records, meta = sim_runner(ex, base, true_vals, args.q_start, log, measure=args.sim_measure)
            source = "the simulated stack"
        else:
            records = measure_runs(true, ex.profiles, args.q_start, Sensors(), np.random.default_rng(args.seed))
            source = "a simulated measurement"
        truth = true.to_dict()
        meta["truth"] = truth
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


def _print_human(out: dict[str, Any]) -> None:
    print(f"{PROG}: {out['message']}")
    for k, v in out["estimates"].items():
        lo, hi = out["interval95"][k]
        print(f"  {k:<3} = {v:.6g} {out['units'][k]}   95 % [{lo:.6g}, {hi:.6g}]"
              + (f"   box ±{100 * out['box'][k]:.2f} %" if k in out["box"] else ""))
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

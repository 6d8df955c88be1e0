"""``ff-reproduce``: recompute the paper's results and write a markdown report with figures.

    ff-reproduce [--out docs/reproduction] [--quick] [--seed S] [--only SECTION ...]

Exit codes: 0 report written; 1 internal error; 2 the output folder cannot be written.
The report itself is :func:`ff_planner.report.reproduce.run`.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Optional, Sequence

from ff_planner.report.reproduce import SECTIONS, run


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``ff-reproduce``."""
    ap = argparse.ArgumentParser(prog="ff-reproduce", description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--out", default="docs/reproduction", help="output folder (default docs/reproduction)")
    ap.add_argument("--quick", action="store_true", help="fewer starts and sweep points")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", nargs="+", choices=list(SECTIONS), help="run only these sections")
    return ap


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point of ``ff-reproduce``; returns the exit code (see module docstring)."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:
        return int(e.code or 0)
    try:
        path = run(Path(args.out), quick=args.quick, seed=args.seed, sections=args.only or SECTIONS)
    except OSError as e:
        print(f"ff-reproduce: error: cannot write to {args.out!r}: {e.strerror or e}", file=sys.stderr)
        return 2
    except Exception as e:  # noqa: BLE001 - no traceback for users
        print(f"ff-reproduce: internal error: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    print(f"ff-reproduce: wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

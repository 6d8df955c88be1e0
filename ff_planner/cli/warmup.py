"""Compile (or load from numba's on-disk cache) every planner kernel, so no request pays for it.

``./run setup`` calls this once after installing; the planner node's workers call it at start.
A cold compile takes tens of seconds to minutes on a 2-core machine; a cached load about 1 s.

    python -m ff_planner.cli.warmup [--quiet]
"""
from __future__ import annotations

import argparse
import sys
import time

from ff_planner.arm import sim as arm_sim
from ff_planner.identify import measure
from ff_planner.model import scara2
from ff_planner.optimize import box_robust, robust1d, robust2d


def _warm_mismatch() -> None:
    """The simulated arm's sub-stepped plant for friction that is not Eq. 9: compiled in the
    simulated drive's process at its first use otherwise (~0.15-0.3 s holding the GIL)."""
    measure.mismatch_steps(0.17, 1.44, -0.05, 0.19, 0.2, 0.3, 0.1, 0.0, 0.25, 0.0, 0.0, 1.0, 0.01, 0.001)


def warm_all(log=print) -> dict[str, float]:
    """Warm the 1-DOF and 2-DOF kernels; returns seconds per part."""

    times: dict[str, float] = {}
    for name, fn in (("arm1dof", robust1d.warmup), ("robust-box", box_robust.warmup),
                     ("scara2", scara2.warm_up),
                     ("robust2d", robust2d.warm_up), ("sim-friction", _warm_mismatch),
                     ("arm-urdf", arm_sim.warm_up)):
        t0 = time.perf_counter()
        fn()
        times[name] = time.perf_counter() - t0
        log(f"[ff] {name} kernels ready in {times[name]:.1f} s")
    return times


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ff_planner.cli.warmup", description=__doc__.split("\n")[0])
    ap.add_argument("--quiet", action="store_true", help="print nothing")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    warm_all(log=(lambda *_: None) if args.quiet else (lambda m: print(m, file=sys.stderr)))
    if not args.quiet:
        print(f"[ff] planner kernels ready in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())

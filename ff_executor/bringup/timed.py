"""Run a node module with settings for timing-critical processes: ``python -m ff_executor.bringup.timed
[--switch-interval S] MODULE [ARGS...]``.

CPython lets a thread that wakes up (a setpoint due, a CAN frame arriving) wait up to the GIL
switch interval (default 5 ms) while another thread of the same process runs Python code; at
10 A on the paper's arm, 1 ms of switch-time error moves the final position by ~0.04 rad. The
bring-up starts the bridge and the simulated driver through this wrapper with a 0.1 ms interval.
"""
from __future__ import annotations

import runpy
import sys


def main(argv: list[str] | None = None) -> None:
    args = list(sys.argv[1:] if argv is None else argv)
    interval = 1e-4
    if args[:1] == ["--switch-interval"]:
        interval = float(args[1])
        args = args[2:]
    if not args:
        raise SystemExit("usage: python -m ff_executor.bringup.timed [--switch-interval S] MODULE [ARGS...]")
    if not 1e-6 <= interval <= 0.1:
        raise SystemExit(f"--switch-interval must be in [1e-6, 0.1] s, got {interval}")
    sys.setswitchinterval(interval)
    module, sys.argv = args[0], args
    runpy.run_module(module, run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    main()

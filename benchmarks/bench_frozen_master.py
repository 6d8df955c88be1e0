"""Frozen-master benchmark: an ``ff-epos`` process holding 0.5 A on the simulated EPOS4 (CST,
10 ms SYNC from the hub, RxPDO1 every SYNC cycle, 0x60C2 = 10 ms) is frozen with SIGSTOP, or
killed with SIGKILL, while SYNC and the master's heartbeat go on from other processes (the hub,
and ``ff_hwbridge.sim.faults.HeartbeatKeeper`` standing for the kernel's broadcast manager on
SocketCAN). Only the drive's interpolation supervision (EMCY 0x8250) can stop the drive.

Per run: ms from the signal to the drive leaving OPERATION ENABLED and to 0 A, by the simulated
drive's own stamps (CLOCK_MONOTONIC, system-wide; the instant is taken just before the signal),
the drive's state and error code, whether the drive had already tripped before the signal, the
age of the master's heartbeat at the drive afterwards. ``--load N`` runs N busy processes
(``python3 -c "while True: pass"``) beside it. ``--control`` adds runs with the supervision off
in the drive (it must keep driving). Prints JSON; ``--out`` writes it too.

    .venv/bin/python benchmarks/bench_frozen_master.py --repeats 10
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from typing import Any

from _common import busy_load, log, report

from ff_hwbridge.sim import faults

BOUND_S = 0.5


def _run(sig: int, supervision: bool) -> dict[str, Any]:
    t = time.monotonic()
    out = faults.frozen_master(sig, supervision=supervision)
    left, zero = out.out_of_enabled_s, out.zero_current_s
    return {"out_of_enabled_ms": None if left is None else round(left * 1e3, 2),
            "zero_current_ms": None if zero is None else round(zero * 1e3, 2),
            "drive_state": out.drive_state, "drive_fault": out.drive_fault,
            "tripped_before_the_signal": out.notes.get("tripped_before_the_signal"),
            "hb_age_after": out.notes.get("hb_age_after"),
            "sync_went_on": out.notes.get("sync_went_on"),
            "current_a_after": out.notes.get("current_a_after"),
            "run_s": round(time.monotonic() - t, 1)}


def _series(sig: int, repeats: int, supervision: bool) -> dict[str, Any]:
    runs: list[dict[str, Any]] = []
    errors: list[str] = []
    for k in range(repeats):
        try:
            r = _run(sig, supervision)
            runs.append(r)
            log(f"{signal.Signals(sig).name} supervision={'on' if supervision else 'off'} "
                f"{k + 1}/{repeats}: {r['drive_state']} {r['drive_fault']} "
                f"out of enabled {r['out_of_enabled_ms']} ms")
        except Exception as exc:  # noqa: BLE001 - counted and shown, the others go on
            errors.append(f"{type(exc).__name__}: {exc}"[:300])
    left = [r["out_of_enabled_ms"] for r in runs if not r["tripped_before_the_signal"]]
    stopped_in_time = sum(1 for v in left if v is not None and v < BOUND_S * 1e3)
    return {"repeats": repeats, "errors": errors, "runs": runs,
            "tripped_before_the_signal": sum(1 for r in runs if r["tripped_before_the_signal"]),
            "within_500ms": stopped_in_time,
            "fault_0x8250": sum(1 for r in runs if r["drive_fault"] == "0x8250"),
            "still_enabled": sum(1 for r in runs if r["drive_state"] == "Operation enabled"),
            "out_of_enabled_ms_max": max((v for v in left if v is not None), default=None)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=10, help="runs per signal")
    ap.add_argument("--load", type=int, default=0, help="busy processes beside the runs")
    ap.add_argument("--control", type=int, default=0,
                    help="also this many SIGSTOP runs with the drive's supervision off")
    ap.add_argument("--out", help="write the JSON here too")
    a = ap.parse_args()
    out: dict[str, Any] = {"benchmark": "frozen_master", "sync_period_s": faults.FROZEN_SYNC_S,
                           "hold_a": faults.HOLD_A, "bound_s": BOUND_S, "load": a.load,
                           "load_avg_1min_at_start": os.getloadavg()[0]}
    with busy_load(a.load):
        out["sigstop"] = _series(signal.SIGSTOP, a.repeats, True)
        out["sigkill"] = _series(signal.SIGKILL, a.repeats, True)
        if a.control:
            out["sigstop_supervision_off"] = _series(signal.SIGSTOP, a.control, False)
    out["load_avg_1min_at_end"] = os.getloadavg()[0]
    report(out, a.out)
    ok = all(out[k]["within_500ms"] == a.repeats for k in ("sigstop", "sigkill"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

"""Bridge benchmark: time from an injected drive fault to the bridge's safe state, and recovery.

Starts the simulated rig (``python -m ff_hwbridge.cli.sim_rig --host-hub PORT``, own process, CAN hub
on 127.0.0.1), connects an :class:`~ff_hwbridge.drive.epos.EposMaster`, enables the drive with a small
current, then per repetition injects a fault through the rig's stdin (EMCY, heartbeat stop,
dropped TPDOs/heartbeats), waits for the latch, clears the fault and calls ``fault_reset()``.

Latency = monotonic time of the latch (this process) − monotonic time just before the command
was written to the rig's stdin (CLOCK_MONOTONIC is system-wide on Linux), so it includes the
pipe and the rig's command handling: an upper bound of the bridge's own reaction. Prints JSON
with p50 / max per fault, the reasons, and whether every reset re-enabled the drive.

Then the fault-injection scenarios across processes (``ff_hwbridge.sim.faults``: master process
SIGKILLed / SIGSTOPped, hub restarted, drive powered late, drive in Fault at start, scaling
mismatch, EMCY warning vs error, envelope breach, e-stop), the executor SIGKILLed mid-motion on
the ROS stack, each ``--fault-repeats`` times: time from the injection to the drive leaving
OPERATION ENABLED and to 0 A by the simulated drive's own stamps, its state and error code, and
the reason the user reads. Last, the stranger's master (canopen + the EPOS4 EDS only) on a fresh
drive and on one left idle for ``--stranger-idle`` s (started first, so the idling overlaps the
rest).

    .venv/bin/python benchmarks/bench_bridge_faults.py --repeats 5 --fault-repeats 3
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from importlib import resources
from pathlib import Path

import numpy as np
from _common import enable_drive

from ff_hwbridge.drive.epos import EposMaster
from ff_hwbridge.protocol.cia402 import State
from ff_hwbridge.sim import faults
from ff_hwbridge.sim.rig_process import RigProcess, rig_master_config

# the executor-kill and stranger scenarios live with their tests (they use the ROS stack / no
# project code at all): import them from the repository root
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _stats(values: list[float | None]) -> dict:
    """Median and max (ms) of the known ``values`` (s); None where none is known."""
    arr = np.asarray([v for v in values if v is not None], dtype=float) * 1000.0
    if not arr.size:
        return {"p50": None, "max": None}
    return {"p50": float(np.median(arr)), "max": float(arr.max())}


def scenario_faults(repeats: int) -> dict:
    """Every scenario of ``ff_hwbridge.sim.faults`` ``repeats`` times: time to leaving OPERATION
    ENABLED and to 0 A by the drive's own stamps, and what the user read."""
    out: dict = {}
    for name in faults.SCENARIOS:
        runs, errors = [], []
        for _ in range(repeats):
            try:
                runs.append(faults.run(name))
            except Exception as exc:  # noqa: BLE001 - counted and shown, the others go on
                errors.append(f"{type(exc).__name__}: {exc}"[:300])
        if not runs:
            out[name] = {"repeats": repeats, "errors": errors}
            continue
        left = [r.out_of_enabled_s for r in runs]
        out[name] = {
            "repeats": repeats, "errors": errors, "must_stop": runs[0].must_stop,
            "stopped": sum(r.stopped for r in runs),
            "out_of_enabled_ms": _stats(left), "zero_current_ms": _stats([r.zero_current_s for r in runs]),
            "within_500ms": sum(1 for v in left if v is not None and v < 0.5),
            "drive_state_and_fault": sorted({f"{r.drive_state}, {r.drive_fault}" for r in runs}),
            "reasons": sorted({r.reason for r in runs}),
            "notes": runs[-1].notes}
    return out


def executor_kill_faults(repeats: int) -> dict:
    """The executor process SIGKILLed mid-motion on the ROS stack (tests/ff_hwbridge/faults)."""
    from tests.ff_hwbridge.faults import executor_kill

    runs = [executor_kill.run() for _ in range(repeats)]
    left = [r["out_of_enabled_s"] for r in runs]
    return {"executor_sigkill": {
        "repeats": repeats, "moving_at_kill": sum(bool(r["moving_at_kill"]) for r in runs),
        "out_of_enabled_ms": _stats(left), "zero_current_ms": _stats([r["zero_current_s"] for r in runs]),
        "stop_bound_ms": 1000.0 * runs[0]["stop_bound_s"] if runs else None,
        "within_bound": sum(1 for r in runs if r["out_of_enabled_s"] is not None
                            and r["out_of_enabled_s"] < r["stop_bound_s"]),
        "statusword_after": sorted({str(r["statusword_after"]) for r in runs}),
        "reasons": sorted({r["reason"] for r in runs})}}


def stranger_master(idle_rig: "RigProcess | None", idle_since: float, idle_s: float) -> dict:
    """The stranger's master (canopen + the EPOS4 EDS only) on a fresh drive and, when
    ``idle_rig`` is given, on one left idle for ``idle_s`` s."""
    from tests.ff_hwbridge.faults import stranger

    eds = str(resources.files("ff_hwbridge.sim") / "epos4.eds")
    out: dict = {}

    def one(rig: RigProcess) -> dict:
        seen = stranger.run({"interface": "remote", "channel": rig.url, "bitrate": 1_000_000}, 1, eds)
        return {"ok": True, "heartbeat_emcy": f"0x{seen['heartbeat_emcy']:04X}",
                "heartbeat_emcy_after_ms": seen["heartbeat_emcy_after_s"] * 1000.0,
                "quick_stop_to_standstill_ms": seen["quick_stop_to_standstill_s"] * 1000.0,
                "state_after_quick_stop": seen["state_after_quick_stop"],
                "reactions_605A_605E_6007_1029": list(seen["reactions"])}

    fresh = RigProcess(["--model", "arm1dof", "--node-ids", "1"], stderr=tempfile.TemporaryFile("w+"))
    try:
        try:
            out["fresh"] = one(fresh)
        except Exception as exc:  # noqa: BLE001 - reported, not fatal to the benchmark
            out["fresh"] = {"ok": False, "error": str(exc)}
    finally:
        fresh.stop(10)
    if idle_rig is not None:
        time.sleep(max(0.0, idle_s - (time.monotonic() - idle_since)))
        try:
            out["idle"] = {"idle_s": time.monotonic() - idle_since, **one(idle_rig)}
        except Exception as exc:  # noqa: BLE001
            out["idle"] = {"ok": False, "error": str(exc)}
    return out


FAULTS = {
    "emcy": ("emcy 1 0x2310", "clear 1"),
    "heartbeat_stop": ("heartbeat 1 off", "heartbeat 1 on"),
    "drop_tx_frames": ("dropnext 1 200 tx", "clear 1"),
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--heartbeat-ms", type=int, default=10)
    ap.add_argument("--heartbeat-timeout", type=float, default=0.04)
    ap.add_argument("--sync-period", type=float, default=0.001)
    ap.add_argument("--fault-repeats", type=int, default=3, help="repeats of each fault scenario")
    ap.add_argument("--no-stack", action="store_true", help="skip the executor kill (ROS stack)")
    ap.add_argument("--stranger-idle", type=float, default=120.0,
                    help="s the stranger's second drive is left idle (0 = skip that run)")
    a = ap.parse_args()
    idle_rig = (RigProcess(["--model", "arm1dof", "--node-ids", "1"], stderr=tempfile.TemporaryFile("w+"))
                if a.stranger_idle > 0 else None)
    idle_since = time.monotonic()
    sim = RigProcess(["--model", "arm1dof", "--node-ids", "1"])
    master = None
    try:
        cfg = rig_master_config(sim.url, "epos4", 10.0, sync_period=a.sync_period,
                                heartbeat_producer_ms=a.heartbeat_ms,
                                heartbeat_timeout=a.heartbeat_timeout, setpoint_timeout=10.0,
                                sdo_timeout=2.0)
        master = EposMaster(cfg)
        if not enable_drive(master):
            print(json.dumps({"error": f"not enabled: {master.states()} {master.fault_reason}"}))
            return 1
        out: dict = {"benchmark": "bridge_faults", "load_avg_1min_at_start": os.getloadavg()[0],
                     "heartbeat_producer_ms": a.heartbeat_ms,
                     "heartbeat_timeout_s": a.heartbeat_timeout, "sync_period_s": a.sync_period,
                     "faults": {}, "cpu_count": os.cpu_count()}
        for name, (inject, clear) in FAULTS.items():
            lat, reasons, recovered, zero_after = [], set(), 0, 0
            for _ in range(a.repeats):
                master.command_currents([0.1])
                time.sleep(0.3)
                t_inj = time.monotonic()
                sim.send(inject)
                while not master.latched and time.monotonic() - t_inj < 5.0:
                    time.sleep(0.0005)
                if master.latched:
                    # the latch is visible before its reaction is sent; the event (stamped at
                    # the latch) is listed once the zero-current reaction went out
                    latches: list[float] = []
                    while not latches and time.monotonic() - t_inj < 5.0:
                        latches = [t for t, text in master.events
                                   if t >= t_inj and text.startswith("safe state")]
                        time.sleep(0.0005)
                    if not latches:          # latched before the injection: spurious
                        reasons.add(f"latched before the injection: {master.fault_reason}")
                    else:
                        lat.append((latches[-1] - t_inj) * 1000.0)
                        reasons.add(str(master.fault_reason).split(":")[0])
                        zero_after += int(master.applied_currents()[0] == 0.0)
                sim.send(clear)
                time.sleep(0.2)
                master.fault_reset()
                recovered += int(master.wait_for_state(State.OPERATION_ENABLED, 3.0))
            arr = np.asarray(lat)
            out["faults"][name] = {
                "detected": len(lat), "repeats": a.repeats,
                "latency_ms_p50": float(np.median(arr)) if lat else None,
                "latency_ms_max": float(arr.max()) if lat else None,
                "within_50ms": int((arr <= 50.0).sum()) if lat else 0,
                "reasons": sorted(reasons), "zero_current_after_latch": zero_after,
                "recovered_after_reset": recovered}
        master.disconnect()
        master = None
        sim.stop(10)
        out["faults"].update(scenario_faults(a.fault_repeats))
        if not a.no_stack:
            out["faults"].update(executor_kill_faults(a.fault_repeats))
        out["stranger_master"] = stranger_master(idle_rig, idle_since, a.stranger_idle)
        out["load_avg_1min"] = os.getloadavg()[0]
        print(json.dumps(out, indent=1))
        return 0
    finally:
        if master is not None:
            master.disconnect()
        sim.stop(10)
        if idle_rig is not None:
            idle_rig.stop(10)


if __name__ == "__main__":
    sys.exit(main())

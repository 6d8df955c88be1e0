"""Bridge benchmark: time from an injected drive fault to the bridge's safe state, and recovery.

Starts the simulated rig (``python -m ff_hwbridge.cli.sim_rig --host-hub PORT``, own process, CAN hub
on 127.0.0.1), connects an :class:`~ff_hwbridge.drive.epos.EposMaster`, enables the drive with a small
current, then per repetition injects a fault through the rig's stdin (EMCY, heartbeat stop,
dropped TPDOs/heartbeats), waits for the latch, clears the fault and calls ``fault_reset()``.

Latency = monotonic time of the latch (this process) − monotonic time just before the command
was written to the rig's stdin (CLOCK_MONOTONIC is system-wide on Linux), so it includes the
pipe and the rig's command handling: an upper bound of the bridge's own reaction. Prints JSON
with p50 / max per fault, the reasons, and whether every reset re-enabled the drive.

Then, per repetition, a master PROCESS (``ff-epos``, the shipped hardware settings: master
heartbeat 100 ms consumed with 300 ms by the drive) holds 0.5 A and is killed (SIGKILL) or frozen
(SIGSTOP): time from the signal to zero current at the simulated drive (the drive's own monotonic
stamp of its error, which zeroes the current at once; also when the polling saw it) and the
drive's state and fault code (what the user reads), through the rig's stdin (``info 1``).

    .venv/bin/python benchmarks/bench_bridge_faults.py --repeats 5
"""
from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

from ff_hwbridge.drive.epos import EposMaster
from ff_hwbridge.protocol.cia402 import State
from ff_hwbridge.sim.rig import RigConfig
from ff_hwbridge.sim.rig_process import RigProcess, rig_master_config


def _info(sim: RigProcess) -> tuple[str, int, float, float]:
    """(state, fault code, applied A, monotonic s of the drive's latest error) of node 1."""
    reply = sim.cmd("info 1")
    m_state = re.search(r"state='([^']*)'", reply)
    m_fault = re.search(r"fault=0x([0-9A-F]{4})", reply)
    m_amps = re.search(r" i=([-0-9.e]+)", reply)
    m_t = re.search(r"error_t=([0-9.]+)", reply)
    if not (m_state and m_fault and m_amps and m_t):
        raise RuntimeError(f"unexpected rig reply: {reply}")
    return m_state.group(1), int(m_fault.group(1), 16), float(m_amps.group(1)), float(m_t.group(1))


def master_process_faults(sim: RigProcess, repeats: int) -> dict:
    """Kill / freeze an ``ff-epos`` process holding 0.5 A; time to zero current at the drive."""
    d = RigConfig().drive_configs()[0]
    cfg_text = json.dumps({
        "bus": {"interface": "remote", "channel": sim.url}, "sync_period": 0.002,
        "heartbeat_producer_ms": 50, "heartbeat_timeout": 1.0, "setpoint_timeout": 30.0,
        "sdo_timeout": 2.0, "master_heartbeat_ms": 100, "master_heartbeat_timeout_ms": 300,
        "rpdo_timeout_ms": 0,
        "joints": [{"name": "joint1", "node_id": 1, "family": "epos4", "current_limit": 10.0,
                    "units": {"nominal_current": d.nominal_current, "torque_constant": d.torque_constant,
                              "counts_per_rev": d.counts_per_rev, "gear_ratio": d.gear_ratio}}]})
    out: dict = {}
    with tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False) as fh:
        fh.write(cfg_text)                   # JSON is YAML
    try:
        for name, sig in (("master_sigkill", signal.SIGKILL), ("master_sigstop", signal.SIGSTOP)):
            times, polled, seen = [], [], set()
            for _ in range(repeats):
                sim.cmd("resetnode 1")       # power-cycle the drive (it is in Fault after a repeat)
                p = subprocess.Popen([sys.executable, "-u", "-m", "ff_hwbridge.cli.epos", "--config",
                                      fh.name, "--enable", "--current", "0.5", "--hold", "60"],
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
                try:
                    assert p.stdout is not None
                    end = time.monotonic() + 30.0
                    while time.monotonic() < end and '"enabled": true' not in p.stdout.readline():
                        pass
                    end = time.monotonic() + 5.0
                    while abs(_info(sim)[2] - 0.5) > 0.003 and time.monotonic() < end:
                        time.sleep(0.01)
                    time.sleep(0.3)
                    t0 = time.monotonic()
                    os.kill(p.pid, sig)
                    while _info(sim)[2] != 0.0 and time.monotonic() - t0 < 3.0:
                        pass
                    seen_ms = (time.monotonic() - t0) * 1000.0
                    state, fault, _, t_err = _info(sim)
                    times.append((t_err - t0) * 1000.0)     # the drive's own stamp (same clock)
                    polled.append(seen_ms)
                    seen.add(f"{state}, 0x{fault:04X}")
                finally:
                    if sig == signal.SIGSTOP:
                        os.kill(p.pid, signal.SIGCONT)
                    p.kill()
                    p.wait(5)
            arr = np.asarray(times)
            out[name] = {"repeats": repeats, "to_zero_current_ms_p50": float(np.median(arr)),
                         "to_zero_current_ms_max": float(arr.max()),
                         "seen_by_polling_ms_max": float(max(polled)),
                         "within_500ms": int((arr < 500.0).sum()), "drive_state_and_fault": sorted(seen)}
    finally:
        os.unlink(fh.name)
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
    a = ap.parse_args()
    sim = RigProcess(["--model", "arm1dof", "--node-ids", "1"])
    master = None
    try:
        cfg = rig_master_config(sim.url, "epos4", 10.0, sync_period=a.sync_period,
                                heartbeat_producer_ms=a.heartbeat_ms,
                                heartbeat_timeout=a.heartbeat_timeout, setpoint_timeout=10.0,
                                sdo_timeout=2.0)
        master = EposMaster(cfg)
        master.connect()
        master.configure()
        master.enable()
        if not master.wait_for_state(State.OPERATION_ENABLED, 3.0):
            print(json.dumps({"error": f"not enabled: {master.states()} {master.fault_reason}"}))
            return 1
        out: dict = {"benchmark": "bridge_faults", "heartbeat_producer_ms": a.heartbeat_ms,
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
        # a clean command channel; the rig's logs (a killed client's websocket) kept apart
        sim2 = RigProcess(["--model", "arm1dof", "--node-ids", "1"], stderr=tempfile.TemporaryFile("w+"))
        try:
            out["faults"].update(master_process_faults(sim2, a.repeats))
        finally:
            sim2.stop(10)
        out["load_avg_1min"] = os.getloadavg()[0]
        print(json.dumps(out, indent=1))
        return 0
    finally:
        if master is not None:
            master.disconnect()
        sim.stop(10)


if __name__ == "__main__":
    sys.exit(main())

"""Hold benchmark: the shipped robot configuration (``config/bridge_epos4_1dof.yaml``, pointed at
the simulated hub) holds 0.5 A for 60 s on the simulated EPOS4 with its interpolation
supervision on (CST, 0x60C2 = the SYNC period: a SYNC cycle without a new target RPDO faults the
drive 0x8250), once on the machine as it is and ``--load-repeats`` times with ``--load`` busy
processes (``python3 -c "while True: pass"``) beside it.

Each hold: the simulated rig in its own process (hub on 127.0.0.1, drive threads SCHED_FIFO as
in the fault scenarios), an ``ff-epos --config ... --channel ws://... --enable --current 0.5
--hold S`` process as the master (its SYNC, its RPDO every cycle). Counted per hold: the drive's
faults (state and 0x603F at the end, instant it left OPERATION ENABLED), the master's latch (its
``safe_state`` line: a false trip, nothing was injected), its exit code, and the frames the
drive received: SYNCs and RxPDO1s (one per cycle when the master keeps the contract).
``--sync-from hub``: SYNC from the hub instead (its timer, another process, at the config's
``sync_period``; the master's config with ``sync_producer: external``), as the simulated stack
runs. Prints JSON; ``--out`` writes it too.

    .venv/bin/python benchmarks/bench_hold.py --duration 60 --load-repeats 10
    .venv/bin/python benchmarks/bench_hold.py --duration 2 --repeats 30 --load-repeats 0   # start-ups

``uptime`` is recorded at the start, between the series and at the end.
"""
from __future__ import annotations

import argparse
import ast
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Optional

import yaml
from _common import busy_load, log, report

from ff_hwbridge.sim import faults
from ff_hwbridge.sim.rig_process import RigProcess

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config" / "bridge_epos4_1dof.yaml"


def _lines(path: str) -> list[dict[str, Any]]:
    out = []
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            try:
                out.append(json.loads(line))
            except ValueError:
                continue
    return out


def hold(config: Path, current: float, duration: float, sync_from: str = "master") -> dict[str, Any]:
    """One hold of ``current`` A for ``duration`` s; what the drive and the master saw."""
    log_file = tempfile.TemporaryFile("w+")
    rig_args = list(faults.RIG_ARGS)
    record = tempfile.NamedTemporaryFile("w", suffix=".json", delete=False).name
    rig_args += ["--record", record]
    result: dict[str, Any] = {}
    if sync_from == "hub":
        data = yaml.safe_load(config.read_text(encoding="utf-8"))
        data["sync_producer"] = "external"
        rig_args += ["--sync-period", str(data["sync_period"])]
        with tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False) as fh:
            yaml.safe_dump(data, fh)
        config = Path(fh.name)
    rig = RigProcess(rig_args, stderr=log_file, ready_timeout=faults.START_TIMEOUT)
    out_file = tempfile.NamedTemporaryFile("w+", suffix=".jsonl", delete=False)
    p: Optional[subprocess.Popen[str]] = None
    try:
        p = subprocess.Popen([sys.executable, "-u", "-m", "ff_hwbridge.cli.epos", "--config", str(config),
                              "--channel", rig.url, "--enable", "--current", str(current),
                              "--hold", str(duration)],
                             stdout=out_file, stderr=subprocess.DEVNULL, text=True)
        t_start = time.monotonic()
        enabled_at: Optional[float] = None
        while time.monotonic() - t_start < faults.START_TIMEOUT and p.poll() is None:
            if any(d.get("enabled") for d in _lines(out_file.name)):
                enabled_at = time.monotonic()
                break
            time.sleep(0.05)
        code = p.wait(duration + faults.START_TIMEOUT)
        info = faults.drive_info(rig)
        lines = _lines(out_file.name)
        latch = next((d["safe_state"] for d in lines if d.get("safe_state")), None)
        rx = ast.literal_eval(info["rx_by_id"]) if info.get("rx_by_id") not in (None, "None") else {}
        left = float(info["left_enabled_t"])
        result = {"enabled": enabled_at is not None, "exit_code": code,
                  "master_latched": latch,
                  "drive_state_at_end": info["state"], "drive_fault": info["fault"],
                  "drive_left_enabled_after_s": (round(left - enabled_at, 3)
                                                 if enabled_at is not None and left > enabled_at else None),
                  "supervision": info.get("supervision"),
                  "interpolation_faults": int(info.get("interpolation_faults", -1)),
                  "interpolation_unjudged": int(info.get("interpolation_unjudged", -1)),
                  "sync_frames": rx.get("0x80", 0), "rpdo1_frames": rx.get("0x201", 0),
                  "held_s": round(time.monotonic() - t_start, 1) if enabled_at is None
                  else round(time.monotonic() - enabled_at, 1)}
    finally:
        if p is not None and p.poll() is None:
            p.kill()
            p.wait(5)
        rig.stop()
        log_file.close()
        out_file.close()
        os.unlink(out_file.name)
        if sync_from == "hub":
            os.unlink(config)
    try:
        with open(record, encoding="utf-8") as rec:
            hub = (json.load(rec).get("hub") or {}).get("sync") or {}
        # the hub's SYNC timer: sends later than their nominal instant (the bus instant stays
        # nominal); a send a period late can make the master's RPDO miss its cycle
        result["hub_sync"] = {k: hub.get(k) for k in ("count", "late_slots", "send_late_p99_us",
                                                       "send_late_max_us")}
    except (OSError, ValueError):
        pass
    finally:
        os.unlink(record)
    return result


def _uptime() -> str:
    """``uptime``'s line (load averages over 1, 5, 15 min)."""
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def _series(n: int, config: Path, current: float, duration: float, sync_from: str) -> dict[str, Any]:
    runs, errors = [], []
    for k in range(n):
        try:
            r = hold(config, current, duration, sync_from)
            runs.append(r)
            log(f"hold {k + 1}/{n}: exit {r['exit_code']}, drive {r['drive_fault']}, latch {r['master_latched']}")
        except Exception as exc:  # noqa: BLE001 - counted and shown, the others go on
            errors.append(f"{type(exc).__name__}: {exc}"[:300])
    return {"holds": n, "errors": errors, "runs": runs,
            "drive_faults": sum(1 for r in runs if r["drive_fault"] not in ("0x0000", "0x0")),
            "drive_fault_codes": sorted({r["drive_fault"] for r in runs}),
            "false_trips": sum(1 for r in runs if r["master_latched"] or r["exit_code"] != 0),
            "clean": sum(1 for r in runs if r["exit_code"] == 0 and not r["master_latched"]
                         and r["drive_fault"] in ("0x0000", "0x0"))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default=str(CONFIG), help="bridge YAML of the master")
    ap.add_argument("--current", type=float, default=0.5, help="A held")
    ap.add_argument("--duration", type=float, default=60.0, help="s per hold")
    ap.add_argument("--repeats", type=int, default=1, help="holds without added load")
    ap.add_argument("--load-repeats", type=int, default=10, help="holds with --load busy processes")
    ap.add_argument("--load", type=int, default=2, help="busy processes beside the loaded holds")
    ap.add_argument("--sync-from", choices=("master", "hub"), default="master",
                    help="SYNC producer: the master (the shipped config) or the hub")
    ap.add_argument("--out", help="write the JSON here too")
    a = ap.parse_args()
    out: dict[str, Any] = {"benchmark": "hold", "config": os.path.relpath(a.config, REPO),
                           "current_a": a.current, "duration_s": a.duration, "sync_from": a.sync_from,
                           "load_avg_1min_at_start": os.getloadavg()[0], "uptime_start": _uptime()}
    out["quiet"] = _series(a.repeats, Path(a.config), a.current, a.duration, a.sync_from)
    out["load_avg_1min_after_quiet"] = os.getloadavg()[0]
    out["uptime_after_quiet"] = _uptime()
    with busy_load(a.load if a.load_repeats else 0):
        out[f"load_{a.load}"] = _series(a.load_repeats, Path(a.config), a.current, a.duration,
                                        a.sync_from)
    out["load_avg_1min_at_end"] = os.getloadavg()[0]
    out["uptime_end"] = _uptime()
    report(out, a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""One-way latency of a CAN frame across the simulation's hub (python-can-remote on 127.0.0.1); JSON.

The latency term of the stack's timing chain after the bridge: the bridge reports when it SENT a
setpoint's RPDO (its ``~/applied`` stamp), the simulated drive applies the current when the frame
ARRIVES. Here a sender process sends a frame every ``--period`` s carrying its due time (sleep until
0.3 ms before, then spin, like the bridge's scheduler), this process receives them through the hub
(a separate process, ``ff-can-hub``) and reports arrival − due and arrival − sent (µs): the common
part moves a whole profile (harmless), the spread between frames moves switches against each other.
``--load N``: N busy processes beside it.

    python benchmarks/bench_hub_latency.py [--frames 3000] [--period 0.001] [--load 2] [--out FILE]
"""
from __future__ import annotations

import argparse
import os
import struct
import subprocess
import sys
import time
from typing import Any

import numpy as np
from _common import busy_processes, percentiles, report, stop_processes

from ff_hwbridge.sim.rig_process import free_port


def sender(url: str, frames: int, period: float) -> None:
    """Send ``frames`` frames, one per ``period`` s, each carrying (due ns, sent ns)."""
    import can

    bus = can.Bus(interface="remote", channel=url, bitrate=1_000_000)
    time.sleep(0.5)
    t0 = time.monotonic_ns() + 200_000_000
    step = int(round(period * 1e9))
    for i in range(frames):
        due = t0 + i * step
        wait = (due - time.monotonic_ns()) / 1e9 - 3e-4
        if wait > 0:
            time.sleep(wait)
        while time.monotonic_ns() < due:
            pass
        sent = time.monotonic_ns()
        bus.send(can.Message(arbitration_id=0x201, data=struct.pack("<II", (due // 1000) & 0xFFFFFFFF,
                                                                    (sent - due) // 1000),
                             is_extended_id=False))
    time.sleep(0.3)
    bus.shutdown()


def main(argv: Any = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=3000)
    ap.add_argument("--period", type=float, default=0.001, help="s")
    ap.add_argument("--load", type=int, default=0)
    ap.add_argument("--out", default=None)
    ap.add_argument("--role", default="measure", help=argparse.SUPPRESS)
    ap.add_argument("--url", default="", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.role == "send":
        sender(a.url, a.frames, a.period)
        return 0
    import can

    port = free_port()
    url = f"ws://127.0.0.1:{port}/"
    procs: list[subprocess.Popen[Any]] = [
        subprocess.Popen([sys.executable, "-m", "ff_hwbridge.cli.can_hub", "--port", str(port)],
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)]
    try:
        line = procs[0].stdout.readline() if procs[0].stdout else ""
        if "CAN hub on" not in line:
            raise RuntimeError(f"hub did not start: {line!r}")
        procs += busy_processes(a.load)
        bus = can.Bus(interface="remote", channel=url, bitrate=1_000_000)
        tx = subprocess.Popen([sys.executable, __file__, "--role", "send", "--url", url,
                               "--frames", str(a.frames), "--period", str(a.period)])
        procs.append(tx)
        late: list[int] = []         # arrival − due, µs
        hop: list[int] = []          # arrival − sent, µs
        end = time.monotonic() + a.frames * a.period + 20.0
        while len(late) < a.frames and time.monotonic() < end:
            m = bus.recv(0.5)
            if m is None:
                if tx.poll() is not None:
                    break
                continue
            now_us = (time.monotonic_ns() // 1000) & 0xFFFFFFFF
            due_us, send_lag_us = struct.unpack("<II", bytes(m.data))
            arrival = (now_us - due_us) & 0xFFFFFFFF
            late.append(arrival)
            hop.append(arrival - send_lag_us)
        bus.shutdown()
    finally:
        stop_processes(procs)
    arr, hops = np.asarray(late, float), np.asarray(hop, float)
    out = {"benchmark": "hub_one_way_latency", "frames_sent": a.frames, "frames_received": int(arr.size),
           "period_s": a.period, "load_processes": a.load, "loadavg_end": list(os.getloadavg()),
           "arrival_minus_due_us": percentiles(arr, mean=False) or None,
           "arrival_minus_sent_us": percentiles(hops, mean=False) or None}
    report(out, a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())

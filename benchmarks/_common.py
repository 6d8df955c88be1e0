"""Pieces the benchmarks share: progress lines on stderr, busy load processes, percentile
summaries, the JSON report (stdout and ``--out``), bringing a drive to OPERATION ENABLED, feeding
a setpoint stream ahead of its stamps, and finding that stream in the simulated drive's log.

Imported by the scripts in this folder as ``from _common import ...`` (a script's own folder is
first on ``sys.path``). No rclpy.
"""
from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import time
from typing import TYPE_CHECKING, Any, Callable, Iterator, Optional, Sequence

import numpy as np

from ff_hwbridge.protocol.cia402 import State
from ff_planner.model.params import Arm1DofParams, default_params

if TYPE_CHECKING:
    from ff_hwbridge.drive.epos import EposMaster
    from ff_hwbridge.drive.player import SetpointPlayer
    from ff_hwbridge.drive.player_process import ProcessPlayer
    from ff_hwbridge.sim.rig_process import RigProcess


def log(s: str) -> None:
    """One progress line on stderr (stdout carries the JSON report)."""
    print(s, file=sys.stderr, flush=True)


def arm1dof_params() -> Arm1DofParams:
    """The planner's default 1-DOF arm model (the paper's table 2)."""
    params = default_params("arm1dof")
    assert isinstance(params, Arm1DofParams)
    return params


def busy_processes(n: int) -> list[subprocess.Popen[bytes]]:
    """``n`` child processes spinning a CPU each (stopped by :func:`stop_processes`)."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"], stdin=subprocess.DEVNULL)
            for _ in range(n)]


def stop_processes(procs: Sequence[subprocess.Popen[Any]]) -> None:
    """Kill each child process and reap it."""
    for p in procs:
        p.kill()
        p.wait()


@contextlib.contextmanager
def busy_load(n: int) -> Iterator[list[subprocess.Popen[bytes]]]:
    """:func:`busy_processes` for the ``with`` block; killed when it ends, however it ends."""
    procs = busy_processes(n)
    try:
        yield procs
    finally:
        stop_processes(procs)


def percentiles(a: np.ndarray, *, mean: bool = True) -> dict[str, float]:
    """p50 / p99 / max / min (and the mean with ``mean``) of ``a``, in its unit; {} when empty."""
    if a.size == 0:
        return {}
    out = {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)),
           "max": float(a.max()), "min": float(a.min())}
    if mean:
        out["mean"] = float(a.mean())
    return out


def report(out: Any, path: Optional[str], *, indent: int = 2,
           default: Optional[Callable[[Any], Any]] = None, final_newline: bool = False) -> None:
    """Print ``out`` as JSON and, with ``path``, write the same text there (UTF-8)."""
    text = json.dumps(out, indent=indent, default=default)
    print(text)
    if path:
        with open(path, "w", encoding="utf-8") as fh:
            fh.write(text + "\n" if final_newline else text)


def enable_drive(master: EposMaster, timeout: float = 3.0) -> bool:
    """Connect, configure and enable ``master``'s drives; whether OPERATION ENABLED came within
    ``timeout`` s."""
    master.connect()
    master.configure()
    master.enable()
    return master.wait_for_state(State.OPERATION_ENABLED, timeout)


def stop_drive(player: SetpointPlayer | ProcessPlayer, master: EposMaster) -> Optional[str]:
    """Close ``player`` and disable ``master``'s drives; the safe-state reason the master held
    before disabling (None when it held none)."""
    player.close()
    reason = master.fault_reason
    master.disable()
    time.sleep(0.05)
    return reason


def release_rig(master: Optional[EposMaster], rig: RigProcess, timeout: float = 20.0) -> None:
    """Disconnect ``master`` (when it was made) and stop the simulated rig (it writes its
    ``--record`` log on the way out), waiting up to ``timeout`` s."""
    if master is not None:
        master.disconnect()
    rig.stop(timeout)


def feed_stream(player: SetpointPlayer | ProcessPlayer, stamps: Sequence[int], currents: Sequence[float], *,
                profile_id: str = "bench", mark_last: bool = False, ahead_ns: int = 100_000_000,
                poll: float = 0.02, on_poll: Optional[Callable[[], None]] = None) -> int:
    """Submit one current (A) per stamp (ns, wall clock), each once its stamp is less than
    ``ahead_ns`` away (as the bridge node feeds its player), then wait until the player has
    played them all. ``mark_last`` flags the final setpoint as the motion's last. Stops feeding at
    the player's first refusal (safe state); ``on_poll()`` is called between batches. Returns how
    many setpoints were submitted."""
    from ff_hwbridge.drive.player import SetpointRejected

    n = len(stamps)
    submitted = 0
    while submitted < n:
        horizon = time.time_ns() + ahead_ns
        try:
            while submitted < n and stamps[submitted] < horizon:
                player.submit(stamps[submitted], [currents[submitted]], seq=submitted,
                              profile_id=profile_id, last=mark_last and submitted == n - 1)
                submitted += 1
        except SetpointRejected:
            break
        if on_poll is not None:
            on_poll()
        time.sleep(poll)
    while player.pending:
        if on_poll is not None:
            on_poll()
        time.sleep(0.01)
    return submitted


def match_stream(raws: Sequence[int], want: Sequence[int], count: int, *, head: int = 20,
                 window: int = 50) -> tuple[Optional[int], list[tuple[int, int]], int]:
    """Find a sent stream in a drive's log of raw setpoints, in order.

    The stream starts where the log first holds ``want[:head]`` in a row (the enable sequence
    writes other setpoints before it). From there each of the first ``count`` wanted values is
    looked for within the next ``window`` log entries; the entries skipped on the way are extra
    (repeats, periodic refreshes). Returns (start index or None, [(stream index, log index)],
    extra entries skipped)."""
    first = list(want[:head])
    start = next((i for i in range(len(raws) - head + 1) if list(raws[i:i + head]) == first), None)
    matched: list[tuple[int, int]] = []
    extra = 0
    if start is None:
        return None, matched, extra
    j = start
    for k in range(count):
        look = j
        while look < len(raws) and look < j + window and raws[look] != want[k]:
            look += 1
        if look < len(raws) and raws[look] == want[k]:
            extra += look - j
            matched.append((k, look))
            j = look + 1
    return start, matched, extra

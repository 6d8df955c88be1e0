"""``ff-identify`` with ``--sim``: run the identification excitation on the simulated ROS stack.

The console script's entry point: ``main`` is ``ff_planner.cli.identify.main`` with the on-stack
runner :func:`run_on_stack` handed in. ROS (rclpy, the stack, the client) is imported only when
``--sim`` runs, so ``ff-identify --records`` needs no ROS (and the planner package, which knows
nothing of execution, never imports this one).

:func:`run_on_stack` starts the simulated stack (``Stack``: sim driver with the given true
parameters, bridge, executor; no planner), then for each run of the excitation checks that the
arm is at rest (the bridge's joint states; a moving arm is refused), sends the run's profile
from the measured position to the executor action (``StackClient.execute``) and keeps the
bridge's joint states (rad, effort = measured current A) as a RunRecord, with the time origin at
the stamp of the run's first setpoint and each switch moved by the delay the bridge applied it
with. Units: rad, rad/s, A, s.
"""
from __future__ import annotations

import math
import sys
import threading
import time
from collections import deque
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy as np

from ff_planner.cli import identify as cli
from ff_planner.identify.excitation import Envelope, Excitation
from ff_planner.identify.records import RunRecord
from ff_planner.model.params import Arm1DofParams
from ff_planner.model.profile import CurrentProfile


#: what a run's record is made of (see ``record_of``)
MEASURES = ("joints", "truth")


class ArmNotAtRest(RuntimeError):
    """The arm moves (or its joint states do not arrive): identification does not start it."""


class StackFault(RuntimeError):
    """A run produced no data: the executor aborted it or the bridge did not apply all its current
    changes (a latched safe state). Not a timing judgement: a run that completed always counts."""


class StackProbe:
    """The bridge's joint states and its fault reset, for the runner; made once per client (rclpy
    entities are not destroyed while the client's executor thread spins)."""

    def __init__(self, client: Any) -> None:
        from sensor_msgs.msg import JointState
        from std_srvs.srv import Trigger

        self._trigger = Trigger
        self._lock = threading.Lock()
        self._samples: deque[tuple[float, float]] = deque(maxlen=400)
        client.node.create_subscription(JointState, "/ff_hwbridge/joint_states", self._on_js, 50)
        self._reset = client.node.create_client(Trigger, "/ff_hwbridge/fault_reset")

    def _on_js(self, m: Any) -> None:
        if m.position:
            with self._lock:
                self._samples.append((float(m.position[0]), float(m.velocity[0]) if m.velocity else 0.0))

    def wait_at_rest(self, q_res: float, window: float = 0.3, rest_velocity: float = 1e-3,
                     timeout: float = 5.0) -> float:
        """Position (rad) of an arm at rest, from the bridge's joint states over ``window`` s:
        |q̇| ≤ rest_velocity and q within 2 encoder counts; ArmNotAtRest after ``timeout`` s."""
        end = time.monotonic() + timeout
        last = "no joint states from the bridge"
        while time.monotonic() < end:
            with self._lock:
                self._samples.clear()
            time.sleep(window)
            with self._lock:
                win = list(self._samples)
            if len(win) >= 3:
                q = np.array([s[0] for s in win])
                v = np.array([s[1] for s in win])
                if np.abs(v).max() <= rest_velocity and np.ptp(q) <= 2.0 * q_res + 1e-12:
                    return float(np.median(q))
                last = f"|v| up to {np.abs(v).max():.3g} rad/s, q spread {np.ptp(q):.3g} rad"
        raise ArmNotAtRest(f"the arm is not at rest ({last}); identification moves an arm only from rest")

    def fault_reset(self, timeout: float = 5.0) -> str:
        """Call the bridge's ``~/fault_reset`` (a latched safe state blocks every setpoint)."""
        if not self._reset.wait_for_service(timeout_sec=timeout):
            return "no /ff_hwbridge/fault_reset service"
        fut = self._reset.call_async(self._trigger.Request())
        end = time.monotonic() + timeout
        while not fut.done() and time.monotonic() < end:
            time.sleep(0.01)
        return str(fut.result().message) if fut.done() else "no answer from /ff_hwbridge/fault_reset"


def applied_profile(profile: CurrentProfile, delays: Sequence[float]) -> CurrentProfile:
    """The profile with each switch moved by its delay (s) relative to the first one: the timing
    the bridge applied (one delay per current change: the steps and the final zero)."""
    if len(delays) != profile.n_steps + 1:
        return profile
    d = np.asarray(delays, float) - float(delays[0])
    st = profile.step_times + d
    if np.any(np.diff(st) <= 0.0) or st[-1] > profile.tf:
        return profile
    return CurrentProfile(st, profile.currents, profile.tf, profile.tf - float(st[-1]))


def record_of(outcome: Any, profile: CurrentProfile, q_res: float, measure: str = "joints") -> RunRecord:
    """RunRecord from a MoveOutcome, time 0 at the profile's first stamp: ``measure`` "joints" =
    the bridge's joint states (the encoder as the bridge reports it, stamped when published);
    "truth" = the simulated arm's ground truth rounded to the encoder quantum (stamped when sampled)."""
    if measure not in MEASURES:
        raise ValueError(f"measure must be one of {MEASURES}, got {measure!r}")
    t, q, _, eff = (outcome.joints if measure == "joints" else outcome.truth).arrays()
    if measure == "truth" and q.size:
        q = np.floor(q / q_res + 0.5) * q_res
    if t.size < 10 or outcome.profile_start is None:
        raise RuntimeError(f"the run recorded {t.size} joint states; too few to fit")
    tr = t - float(outcome.profile_start)
    order = np.argsort(tr, kind="stable")
    tr, q, eff = tr[order], q[order, 0], eff[order, 0]
    keep = np.concatenate([[True], np.diff(tr) > 0.0])
    return RunRecord(tr[keep], q[keep], eff[keep], applied_profile(profile, outcome.switch_delays), q_res)


def execute_run(client: Any, probe: StackProbe, run: Any, q_res: float, envelope: Envelope, *,
                log: Callable[[str], None] = print,
                measure: str = "joints") -> tuple[RunRecord, list[float]]:
    """Execute one run from rest and check it. Every completed run counts, however late its
    switches (no timing gate): the fit uses the switch times as the bridge applied them, so a late
    switch is data, not noise. A run that left ``envelope`` stops the identification
    (RuntimeError); one that did not complete, or whose current changes the bridge did not all
    apply (a latched safe state), raises StackFault."""
    from ff_msgs_py.convert import profile_to_msg

    q = probe.wait_at_rest(q_res)
    msg = profile_to_msg(run.profile, "arm1dof", [q], [q + run.q_end - run.q0])
    mv = client.execute(msg, timeout=run.profile.tf + 15.0)
    _, qs, _, _ = mv.joints.arrays()
    if qs.size and (qs.min() < envelope.q_min - 1e-9 or qs.max() > envelope.q_max + 1e-9):
        raise RuntimeError(f"the arm left the envelope [{envelope.q_min:.4g}, {envelope.q_max:.4g}] rad "
                           f"(reached [{qs.min():.4g}, {qs.max():.4g}] rad; switch delays "
                           f"{np.round(mv.switch_delays, 4).tolist()} s): identification stopped")
    if not mv.succeeded:
        raise StackFault(f"the executor did not complete a run: {mv.result.message}")
    if len(mv.switch_delays) != run.profile.n_steps + 1:
        raise StackFault(f"the bridge applied {len(mv.switch_delays)} of {run.profile.n_steps + 1} current "
                         f"changes of a run (safe state? ff-ctl diag)")
    return record_of(mv, run.profile, q_res, measure), [float(x) for x in mv.switch_delays]


def run_on_stack(ex: Excitation, base: Arm1DofParams, true_params: Mapping[str, float], q_start: float,
                 log: Callable[[str], None] = print, run_dir: Optional[str] = None,
                 stack_log: Optional[Callable[[str], None]] = None,
                 measure: str = "joints", envelope: Optional[Envelope] = None,
                 rt_priority: int = 10) -> tuple[list[RunRecord], dict]:
    """Start the simulated stack with ``true_params``, run every profile of ``ex`` through the
    executor, return (records, meta); ``measure`` as in ``record_of``; ``envelope`` (default: the
    excitation's) bounds the measured positions; ``rt_priority``: SCHED_FIFO priority of the
    simulated drive and the bridge's scheduler thread where permitted (as ``ff-demo``; 0 = normal).
    Every completed run counts; a run that produced no data (StackFault) is run once more after a
    fault reset, and named in ``meta["stack_faults"]``. The stack and the client stop on return or
    error."""
    if measure not in MEASURES:
        raise ValueError(f"measure must be one of {MEASURES}, got {measure!r}")
    from ff_executor.bringup.stack import COUNTS_PER_REV, Stack, StackOptions
    from ff_executor.ros.client import StackClient

    env = envelope or ex.envelope
    if env is None:
        raise ValueError("run_on_stack needs the envelope the excitation was designed for")
    q_res = 2.0 * math.pi / (COUNTS_PER_REV * float(base.n))
    opts = StackOptions(true_params=dict(true_params), planner=False, q0=[float(q_start)], run_dir=run_dir,
                        rt_priority=int(rt_priority))
    records: list[RunRecord] = []
    delays: list[list[float]] = []
    faults: list[str] = []
    t0 = time.monotonic()
    with Stack(opts, log=stack_log or (lambda s: None)) as stack:
        client = StackClient(stack.env, "ff_identify")
        try:
            probe = StackProbe(client)
            for k, run in enumerate(ex.runs):
                try:
                    rec, dl = execute_run(client, probe, run, q_res, env, log=log, measure=measure)
                except StackFault as exc:      # no data: reset the bridge, run it once more
                    faults.append(f"run {k + 1}: {exc}; fault reset: {probe.fault_reset()}")
                    log(f"  stack fault, run {k + 1} again: {faults[-1]}")
                    rec, dl = execute_run(client, probe, run, q_res, env, log=log, measure=measure)
                records.append(rec)
                delays.append(dl)
                log(f"  run {k + 1}/{len(ex.runs)}: {run.direction * run.level:+.3g} A, "
                    f"{rec.t.size} samples, switch delays {np.round(dl, 4).tolist()} s")
        finally:
            client.close()
    meta = {"source": f"simulated stack ({measure})", "wall_s": time.monotonic() - t0, "switch_delays": delays,
            "stack_faults": faults,
            "q_resolution": q_res}
    return records, meta


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Console script ``ff-identify`` (see ``ff_planner.cli.identify``), ``--sim`` on the stack."""
    return cli.main(argv, sim_runner=run_on_stack)


if __name__ == "__main__":
    sys.exit(main())

"""``ff-identify`` with ``--sim``: run the identification excitation on the simulated ROS stack.

The console script's entry point: ``main`` is ``ff_planner.cli.identify.main`` with the on-stack
runner :func:`run_on_stack` handed in. ROS (rclpy, the stack, the client) is imported only when
``--sim`` runs, so ``ff-identify --records`` needs no ROS (and the planner package, which knows
nothing of execution, never imports this one).

:func:`run_on_stack` starts the simulated stack (``identification_options``: sim driver with the
given true parameters — and, optionally, friction that is not Eq. 9 —, bridge latching setpoints
at SYNC, executor; no planner) and hands it to :func:`identify_runs`, which works on any running
stack: before the first run the executor and the bridge must answer and no drive may be in fault
(``StackProbe.check_stack``: ``StackNotRunning``, ``DriveFault``), before each run the arm must be
at rest (``ArmNotAtRest``); each run's profile goes from the measured position to the executor
action (``StackClient.execute``) and its samples become a RunRecord. The timing comes from the
CAN bus (``ff_executor.bringup.bus_monitor``): each current change at the SYNC that latched its
RPDO, the currents as the drive decoded them (its 3 mA quantum); with the monitor of
``bus_monitor`` (a ``StackBus``) the samples too are read off the bus
(``ff_executor.bringup.bus_feedback``): each TPDO1's position at the SYNC it certainly answered,
not the bridge's joint state, whose stamp is the latest SYNC the bridge saw — one SYNC (10 ms)
late for an answer that came more than a period after its SYNC (on a loaded host one such
sample, 12.7 encoder counts off, made a true-Eq. 9 fit say "MODEL MISMATCH"). With a plain
BusMonitor the bridge's joint states placed by their stamps; without a bus monitor, the bridge's
stamps and reported switch delays (less exact). Units: rad, rad/s, A, s.
"""
from __future__ import annotations

import math
import os
import sys
import threading
import time
from collections import deque
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy as np

from ff_executor.bringup.bus_feedback import BusFeedback, StackBus
from ff_executor.bringup.bus_monitor import BusMonitor
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


class StackNotRunning(RuntimeError):
    """The stack's executor or bridge does not answer: nothing was sent."""


class DriveFault(RuntimeError):
    """The bridge reports a latched safe state or a drive fault: nothing is sent until it is
    cleared (``ff-ctl fault-reset`` after the cause is fixed)."""


class StackProbe:
    """The bridge's joint states, its diagnostics and its fault reset, for the runner; made once
    per client (rclpy entities are not destroyed while the client's executor thread spins)."""

    def __init__(self, client: Any) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from sensor_msgs.msg import JointState
        from std_srvs.srv import Trigger

        self._client = client
        self._trigger = Trigger
        self._lock = threading.Lock()
        self._samples: deque[tuple[float, float]] = deque(maxlen=400)
        self._diag: dict[str, tuple[int, str]] = {}      # status name -> (level, message)
        self._late: Optional[tuple[float, int]] = None    # (monotonic s, sim driver's late_switches)
        self.last_rest: Optional[float] = None            # rad, the last position wait_at_rest returned
        client.node.create_subscription(JointState, "/ff_hwbridge/joint_states", self._on_js, 50)
        client.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 20)
        self._reset = client.node.create_client(Trigger, "/ff_hwbridge/fault_reset")

    def _on_js(self, m: Any) -> None:
        if m.position:
            with self._lock:
                self._samples.append((float(m.position[0]), float(m.velocity[0]) if m.velocity else 0.0))

    def _on_diag(self, m: Any) -> None:
        with self._lock:
            for st in m.status:
                if st.name.startswith("ff_hwbridge"):
                    self._diag[st.name] = (int.from_bytes(st.level, "little") if isinstance(st.level, bytes)
                                           else int(st.level), str(st.message))
                elif st.name.startswith("ff_sim_driver"):
                    for kv in st.values:
                        if kv.key == "late_switches":
                            self._late = (time.monotonic(), int(kv.value))

    def sim_late_switches(self, fresh: float = 0.0) -> Optional[int]:
        """The simulated arm's count of current changes that started late (their CAN frames
        handled after the plant's lag: the bus then shows an instant the plant did not use), from
        the sim driver's diagnostics, waiting up to 1.5 s for one newer than ``fresh`` s ago;
        None without a simulated driver."""
        end = time.monotonic() + (1.5 if fresh > 0.0 else 0.0)
        while True:
            with self._lock:
                late = self._late
            if late is not None and (fresh <= 0.0 or late[0] >= time.monotonic() - fresh):
                return late[1]
            if time.monotonic() >= end:
                return late[1] if late is not None else None
            time.sleep(0.05)

    def check_stack(self, timeout: float = 5.0) -> None:
        """StackNotRunning unless the executor action and the bridge's joint states answer within
        ``timeout`` s; then ``check_drive``."""
        if not self._client.action.wait_for_server(timeout_sec=timeout):
            raise StackNotRunning(
                f"no executor action /ff_executor/execute in ROS domain {os.environ.get('ROS_DOMAIN_ID', '0')} "
                f"(loopback) within {timeout:g} s: is the stack running (ff-bringup)? nothing was sent")
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self._lock:
                if self._samples and self._diag:
                    break
            time.sleep(0.05)
        with self._lock:
            seen, diag = bool(self._samples), bool(self._diag)
        if not seen:
            raise StackNotRunning(f"no joint states from the bridge (/ff_hwbridge/joint_states) within "
                                  f"{timeout:g} s: is the bridge active? nothing was sent")
        if not diag:
            raise StackNotRunning(f"no diagnostics from the bridge (/diagnostics) within {timeout:g} s: "
                                  "cannot tell whether its drives are in fault; nothing was sent")
        self.check_drive()

    def check_drive(self) -> None:
        """DriveFault when the bridge's latest diagnostics report an error (a latched safe state,
        a drive in fault)."""
        with self._lock:
            bad = [f"{name}: {msg}" for name, (level, msg) in self._diag.items() if level >= 2]
        if bad:
            raise DriveFault(f"the drive is in fault ({bad[0]}); clear the cause and call "
                             "ff-ctl fault-reset; nothing was sent")

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
                    self.last_rest = float(np.median(q))
                    return self.last_rest
                last = f"|v| up to {np.abs(v).max():.3g} rad/s, q spread {np.ptp(q):.3g} rad"
        raise ArmNotAtRest(f"the arm is not at rest ({last}); identification moves an arm only from rest")

    def fault_reset(self, timeout: float = 5.0) -> str:
        """Call the bridge's ``~/fault_reset`` (a latched safe state blocks every setpoint) and
        wait up to ``timeout`` s for diagnostics sent after it that report no error."""
        if not self._reset.wait_for_service(timeout_sec=timeout):
            return "no /ff_hwbridge/fault_reset service"
        fut = self._reset.call_async(self._trigger.Request())
        end = time.monotonic() + timeout
        while not fut.done() and time.monotonic() < end:
            time.sleep(0.01)
        if not fut.done():
            return "no answer from /ff_hwbridge/fault_reset"
        with self._lock:
            self._diag.clear()                     # only diagnostics sent after the reset count
        while time.monotonic() < end:
            with self._lock:
                levels = [lv for lv, _ in self._diag.values()]
            if levels and max(levels) < 2:
                break
            time.sleep(0.05)
        return str(fut.result().message)


def switch_changes(currents: Any) -> list[int]:
    """Indices j of the switches that change the current, for step currents (A; N, or N × joints):
    step starts j = 0 .. N − 1 whose current differs from the step before (0 A before the first),
    and j = N, the coast start, when the last step's current is not 0."""
    cur = np.asarray(currents, float)
    cur = cur.reshape(cur.shape[0], -1)
    prev = np.zeros(cur.shape[1])
    out = []
    for j in range(cur.shape[0]):
        if np.any(cur[j] != prev):
            out.append(j)
        prev = cur[j]
    if np.any(prev != 0.0):
        out.append(cur.shape[0])
    return out


def applied_profile(profile: CurrentProfile, delays: Sequence[float]) -> CurrentProfile:
    """The profile with each switch moved by its delay (s) relative to the first one: the timing
    the bridge applied (one delay per current change: the steps whose current differs from the
    one before, and the final zero; a switch between two equal currents changes nothing and
    moves with the change before it). The profile itself when the delays do not fit."""
    changes = switch_changes(profile.currents)
    if len(delays) != len(changes) or not changes:
        return profile
    per = np.empty(profile.n_steps + 1)
    k = -1
    for j in range(profile.n_steps + 1):
        if k + 1 < len(changes) and changes[k + 1] == j:
            k += 1
        per[j] = float(delays[max(k, 0)])
    d = per - float(delays[0])
    st = profile.step_times + d
    if np.any(np.diff(st) <= 0.0) or st[-1] > profile.tf:
        return profile
    return CurrentProfile(st, profile.currents, profile.tf, profile.tf - float(st[-1]))


def record_of(outcome: Any, profile: CurrentProfile, q_res: float, measure: str = "joints",
              bus: Optional[BusMonitor] = None) -> RunRecord:
    """RunRecord from a MoveOutcome: ``measure`` "joints" = the drive's encoder, "truth" = the
    simulated arm's ground truth rounded to the encoder quantum (stamped when sampled). With
    ``bus`` (joints only) the timing is the bus's, the profile as the drive applied it
    (``bus_profile``), and with a ``StackBus`` the samples are the drive's TPDO1 answers read off
    the bus over the span of the run's joint states (``bus_samples``: each at the SYNC it
    answered, ``q_res`` rad per increment); with a plain BusMonitor the bridge's joint states
    placed by their stamps (``bus_timing``); without a bus, time 0 is the profile's first stamp,
    samples at the bridge's stamps and each switch moved by the delay the bridge reports."""
    if measure not in MEASURES:
        raise ValueError(f"measure must be one of {MEASURES}, got {measure!r}")
    t, q, _, eff = (outcome.joints if measure == "joints" else outcome.truth).arrays()
    if measure == "truth" and q.size:
        q = np.floor(q / q_res + 0.5) * q_res
    if t.size < 10 or outcome.profile_start is None:
        raise RuntimeError(f"the run recorded {t.size} joint states; too few to fit")
    q, eff = q[:, 0], eff[:, 0]
    applied = None
    if isinstance(bus, StackBus) and measure == "joints":
        # StackFault when the drive did not apply the profile as sent, or too few answers: no data
        t0, applied = bus_profile(bus, profile, float(outcome.profile_start))
        t, q, eff = bus_samples(bus.feedback, float(t.min()), float(t.max()), t0, q_res)
        eff = np.where(np.isfinite(eff), eff, [applied.current_at(x)[0] for x in t])
    elif bus is not None and measure == "joints":
        t, applied, keep = bus_timing(bus, t, profile, float(outcome.profile_start))
        q, eff = q[keep], eff[keep]
    if applied is None:
        t = t - float(outcome.profile_start)
        applied = applied_profile(profile, outcome.switch_delays)
    order = np.argsort(t, kind="stable")
    t, q, eff = t[order], q[order], eff[order]
    keep = np.concatenate([[True], np.diff(t) > 0.0])
    return RunRecord(t[keep], q[keep], eff[keep], applied, q_res)


def bus_profile(bus: BusMonitor, profile: CurrentProfile, start: float, tol: float = 0.01,
                latched: Optional[bool] = None) -> tuple[float, CurrentProfile]:
    """(t0 bus s, applied profile with time 0 at t0): the drive's current changes between
    ``start`` − 0.1 s and the profile's end + 0.2 s (the bus time of each RPDO that changed it,
    or with ``latched`` — None: the monitor's — of the first SYNC after it; the currents as the
    drive decoded them, each within ``tol`` A of a commanded one, in order), t0 the first.
    StackFault (saying which) when the bus did not show the profile's changes in order ending at
    zero."""
    changes = bus.current_changes(start - 0.1, start + (profile.tf - profile.coast) + 0.2, latched)
    while changes and changes[0][1] == 0.0:
        changes.pop(0)
    if len(changes) < 2 or changes[-1][1] != 0.0:
        raise StackFault(f"the CAN bus showed current changes {[round(a, 4) for _, a in changes]} A for a run "
                         f"of {profile.currents[:, 0].round(4).tolist()} A then 0: the run gave no data")
    amps = np.array([a for _, a in changes[:-1]])
    # the drive's currents are the commanded ones in order (a step latched together with the
    # next one at a late SYNC never took effect: it is missing, not wrong)
    cmd, j = list(profile.currents[:, 0]), 0
    for a in amps:
        while j < len(cmd) and abs(a - cmd[j]) > tol:
            j += 1
        if j == len(cmd):
            raise StackFault(f"the CAN bus showed current changes {amps.round(4).tolist()} A, not those of the "
                             f"run ({profile.currents[:, 0].round(4).tolist()} A) in order: the run gave no data")
        j += 1
    t0 = changes[0][0]
    st = np.array([c[0] - t0 for c in changes])          # the steps' starts and the last one's end
    return t0, CurrentProfile(st, amps.reshape(-1, 1), float(st[-1]) + profile.coast, profile.coast)


def bus_samples(feedback: BusFeedback, t_from: float, t_to: float, t0: float,
                q_res: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t s from ``t0``, q rad, current A — NaN where not placed) of the drive's TPDO answers
    placed at SYNCs in [t_from, t_to] bus s (``BusFeedback.samples``; ``q_res`` rad per encoder
    increment, signed: negative for a joint that counts against the motor). StackFault when
    fewer than half the SYNCs there (or fewer than 20) have a placed answer: the drive process
    stalled through the run."""
    t, counts, amps = feedback.samples(t_from, t_to)
    syncs = feedback.sync_count(t_from, t_to)
    if t.size < max(20, 0.5 * syncs):
        raise StackFault(f"only {t.size} of the {syncs} SYNCs of the run have a drive answer placed on the bus "
                         f"({feedback.unplaced} answers not placed so far): the run gave no data")
    return t - t0, counts * q_res, amps


def bus_timing(bus: BusMonitor, stamps: np.ndarray, profile: CurrentProfile, start: float, tol: float = 0.01,
               latched: Optional[bool] = None) -> tuple[np.ndarray, CurrentProfile, np.ndarray]:
    """(sample times s, applied profile, mask of the stamps kept) on the bus's clock, time 0 at
    the RPDO that started the profile (``bus_profile``), each joint state placed by its stamp
    (``BusMonitor.sample_instants``: the bridge's stamp — a TPDO1's bus time or the SYNC the
    bridge paired it with — trusted as it is). StackFault (saying which) when the bus did not
    show the profile's changes, or too few samples could be placed."""
    t0, applied = bus_profile(bus, profile, start, tol, latched)
    inst = bus.sample_instants(stamps)
    keep = np.isfinite(inst)
    # a joint state that cannot be placed (neither a paired TPDO's bus time nor a SYNC instant)
    # is left out; half will do
    if keep.sum() < max(20, 0.5 * stamps.size):
        raise StackFault(f"only {int(keep.sum())} of the run's {stamps.size} joint states could be placed at the "
                         f"SYNC they were sampled at ({bus.unpaired} drive answers not paired so far): the run "
                         "gave no data")
    return inst[keep] - t0, applied, keep


def execute_run(client: Any, probe: StackProbe, run: Any, q_res: float, envelope: Envelope, *,
                log: Callable[[str], None] = print, measure: str = "joints",
                bus: Optional[BusMonitor] = None,
                outcomes: Optional[list] = None) -> tuple[RunRecord, list[float]]:
    """Execute one run from rest and check it (``outcomes``: a list the run's (MoveOutcome,
    profile) is appended to when it gave data). Every completed run counts, however late its
    switches (no timing gate): the fit uses the switch times as the drive applied them (``bus``)
    or as the bridge reports them, so a late switch is data, not noise. A run that left
    ``envelope`` stops the identification (RuntimeError); one that did not complete, or whose
    current changes the bridge did not all apply (a latched safe state), raises StackFault."""
    from ff_msgs_py.convert import profile_to_msg

    q = probe.wait_at_rest(q_res)
    probe.check_drive()
    reach = run.reach
    if q + reach[0] < envelope.q_min - 1e-9 or q + reach[1] > envelope.q_max + 1e-9:
        raise RuntimeError(f"the arm rests at {q:.4g} rad, {q - run.q0:+.4g} rad from where the run was "
                           f"designed to start: it could reach [{q + reach[0]:.4g}, {q + reach[1]:.4g}] rad, "
                           f"outside the envelope [{envelope.q_min:.4g}, {envelope.q_max:.4g}] rad; "
                           "identification stopped, nothing was sent")
    msg = profile_to_msg(run.profile, "arm1dof", [q], [q + run.q_end - run.q0])
    mv = client.execute(msg, timeout=run.profile.tf + 15.0)
    ts, qs, _, _ = mv.joints.arrays()
    if qs.size and (qs.min() < envelope.q_min - 1e-9 or qs.max() > envelope.q_max + 1e-9):
        raise RuntimeError(f"the arm left the envelope [{envelope.q_min:.4g}, {envelope.q_max:.4g}] rad "
                           f"(from rest at {q:.4g} rad it reached [{qs.min():.4g}, {qs.max():.4g}] rad; switch "
                           f"delays {np.round(mv.switch_delays, 4).tolist()} s; {mv.result.message}): "
                           "identification stopped")
    if not mv.succeeded:
        raise StackFault(f"the executor did not complete a run: {mv.result.message}")
    changes = len(switch_changes(run.profile.currents))
    if len(mv.switch_delays) != changes:
        raise StackFault(f"the bridge applied {len(mv.switch_delays)} of {changes} current "
                         f"changes of a run (safe state? ff-ctl diag)")
    if bus is not None:
        bus.wait_seen(float(ts.max()) if ts.size else time.time(), timeout=2.0)   # the run's last frames
    rec = record_of(mv, run.profile, q_res, measure, bus)
    if float(np.ptp(rec.q)) < 100.0 * q_res:         # every run moves the arm by tenths of a rad
        raise StackFault(f"the arm moved {float(np.ptp(rec.q)):.3g} rad in a run: the drive did not apply it")
    if outcomes is not None:
        outcomes.append((mv, run.profile))
    return rec, [float(x) for x in mv.switch_delays]


def identify_runs(client: Any, ex: Excitation, q_res: float, envelope: Envelope, *,
                  probe: Optional[StackProbe] = None, bus: Optional[BusMonitor] = None,
                  log: Callable[[str], None] = print, measure: str = "joints",
                  retries: int = 2, outcomes: Optional[list] = None) -> tuple[list[RunRecord], dict]:
    """Run every profile of ``ex`` through a running stack's executor (``client``: a
    ``StackClient``), return (records, meta). Before the first run: the stack must answer
    (``StackProbe.check_stack``) and the drive must not be in fault; before each run the arm must
    be at rest. A run that produced no data (StackFault: the executor aborted it, or the bridge
    latched a safe state before all its current changes: there is no partial data) is run again
    after a fault reset, at most ``retries`` times, and named in ``meta["stack_faults"]``; one
    that gave no data but moved the arm is not repeated (the next run starts where it ended, as
    designed) but left out, at most ``retries`` of them (``meta["lost_runs"]``, 1-based); a run
    that completed always counts. ``outcomes``: as in ``execute_run``."""
    probe = probe or StackProbe(client)
    probe.check_stack()
    late0 = probe.sim_late_switches(fresh=2.0)
    records: list[RunRecord] = []
    delays: list[list[float]] = []
    faults: list[str] = []
    t0 = time.monotonic()
    lost: list[int] = []
    for k, run in enumerate(ex.runs):
        rec = None
        for attempt in range(1, retries + 2):
            try:
                rec, dl = execute_run(client, probe, run, q_res, envelope, log=log, measure=measure, bus=bus,
                                      outcomes=outcomes)
                break
            except StackFault as exc:      # no data: reset the bridge, run it again
                q_before = probe.last_rest
                faults.append(f"run {k + 1}: {exc}; fault reset: {probe.fault_reset()}")
                q_now = probe.wait_at_rest(q_res)
                if q_before is not None and abs(q_now - q_before) > 100.0 * q_res and len(lost) < retries:
                    # the run moved the arm: the sequence goes on from where it stopped (each run
                    # starts where the one before ended); its data is lost, not repeated
                    lost.append(k + 1)
                    log(f"  stack fault, run {k + 1} moved the arm and gave no data; next run: {faults[-1]}")
                    break
                log(f"  stack fault, run {k + 1} again: {faults[-1]}")
                if attempt > retries:
                    raise
            except DriveFault as exc:      # latched since the last run (e.g. its final zero was late)
                if k == 0 and attempt == 1 or attempt > retries:
                    raise                  # a fault before anything moved, or one a reset does not clear
                faults.append(f"before run {k + 1}: {exc}; fault reset: {probe.fault_reset()}")
                log(f"  safe state, reset, run {k + 1}: {faults[-1]}")
        if rec is None:
            continue
        records.append(rec)
        delays.append(dl)
        log(f"  run {k + 1}/{len(ex.runs)}: {run.direction * run.level:+.3g} A, "
            f"{rec.t.size} samples, switch delays {np.round(dl, 4).tolist()} s")
    timing = "bus (SYNC instants, RPDO bus times)" if bus is not None else "bridge stamps"
    on_bus = isinstance(bus, StackBus) and measure == "joints"
    meta: dict[str, Any] = {
        "source": f"simulated stack ({measure}; timing: {timing})", "wall_s": time.monotonic() - t0,
        "switch_delays": delays, "stack_faults": faults, "lost_runs": lost, "q_resolution": q_res,
        "timing": "bus" if bus is not None else "bridge",
        "samples": "bus (TPDO1 answers at their SYNC)" if on_bus else measure}
    if bus is not None:
        seen: dict[str, int] = {"syncs": bus.syncs, "tpdo_unpaired": bus.unpaired}
        if isinstance(bus, StackBus):
            seen["tpdo_unplaced"] = bus.feedback.unplaced
        meta["bus"] = seen
    late1 = probe.sim_late_switches(fresh=1.0) if late0 is not None else None
    if late0 is not None and late1 is not None:
        meta["sim_late_switches"] = late1 - late0
    return records, meta


def stack_q_resolution(base: Arm1DofParams) -> float:
    """rad per encoder count of the simulated stack's joint (2π / (counts per rev · gear))."""
    from ff_executor.bringup.stack import COUNTS_PER_REV

    return 2.0 * math.pi / (COUNTS_PER_REV * float(base.n))


#: executor settings of an identification stack: setpoints 0.8 s ahead of their stamps (a late
#: brake switch cannot be corrected by a feedforward run: it overshoots), moves starting 1 s out
IDENTIFY_EXECUTOR = {"lead_time": 0.8, "start_margin": 1.0}


#: the bridge's safe-state envelope around an identification envelope: this fraction of its span
#: beyond each end, and this factor on its speed (the design keeps every prior corner inside the
#: envelope itself; the bridge stops an arm whose friction is far outside the prior)
GUARD_MARGIN = 0.1
GUARD_SPEED = 1.25


def guard_envelope(envelope: Envelope) -> tuple[float, float, float]:
    """(q_min, q_max, v_max) of the bridge's envelope for an identification in ``envelope``."""
    m = GUARD_MARGIN * (envelope.q_max - envelope.q_min)
    return envelope.q_min - m, envelope.q_max + m, GUARD_SPEED * envelope.v_max


def identification_options(true_params: Mapping[str, float] = {}, *, q_start: float = 0.0,
                           friction: Optional[Mapping[str, float]] = None, run_dir: Optional[str] = None,
                           rt_priority: int = 0, setpoint_timing: str = "sync", planner: bool = False,
                           envelope: Optional[Envelope] = None, **more: Any) -> Any:
    """StackOptions of a simulated stack to identify on: ``true_params`` (SI) and ``friction``
    (not Eq. 9, ``StackOptions.sim_friction``) for the arm, setpoints latched at SYNC
    (``setpoint_timing`` "sync": an instant the bus shows exactly), ``IDENTIFY_EXECUTOR`` timing,
    SCHED_FIFO ``rt_priority`` for the simulated drive and the bridge's scheduler where permitted,
    with ``planner`` a planner that rounds its plans' currents to the drive's setpoint quantum
    (EPOS4: per mille of the nominal current) and certifies the rounded profile; with
    ``envelope`` the bridge latches its safe state outside ``guard_envelope(envelope)``;
    ``more``: other StackOptions fields."""
    from ff_executor.bringup.stack import NOMINAL_CURRENT, StackOptions

    ex_over = dict(IDENTIFY_EXECUTOR)
    ex_over.update(more.pop("executor_overrides", {}) or {})
    pl_over = {"current_quantum": NOMINAL_CURRENT / 1000.0}     # EPOS4: per mille of the nominal current
    pl_over.update(more.pop("planner_overrides", {}) or {})
    return StackOptions(true_params=dict(true_params), planner=planner, q0=[float(q_start)], run_dir=run_dir,
                        rt_priority=int(rt_priority), sim_friction=dict(friction or {}),
                        setpoint_timing=setpoint_timing, executor_overrides=ex_over, planner_overrides=pl_over,
                        joint_envelope=guard_envelope(envelope) if envelope is not None else None, **more)


def bus_monitor(stack: Any) -> StackBus:
    """A StackBus (BusMonitor + the drive's samples off the bus) on ``stack``'s CAN hub for its
    first drive (latched setpoints in sync mode)."""
    from ff_executor.bringup.stack import NOMINAL_CURRENT

    return StackBus(stack.hub_url, nominal_current=NOMINAL_CURRENT,
                    latched=stack.options.setpoint_timing == "sync")


def run_on_stack(ex: Excitation, base: Arm1DofParams, true_params: Mapping[str, float], q_start: float,
                 log: Callable[[str], None] = print, run_dir: Optional[str] = None,
                 stack_log: Optional[Callable[[str], None]] = None,
                 measure: str = "joints", envelope: Optional[Envelope] = None,
                 rt_priority: int = 0, bus_times: bool = True,
                 friction: Optional[Mapping[str, float]] = None,
                 setpoint_timing: str = "sync") -> tuple[list[RunRecord], dict]:
    """Start the simulated stack (``identification_options``: ``true_params``, ``friction`` —
    the arm's friction that is not Eq. 9 —, ``setpoint_timing``, ``rt_priority``), run every
    profile of ``ex`` through the executor (``identify_runs``), return (records, meta);
    ``measure`` as in ``record_of``; ``envelope`` (default: the excitation's) bounds the measured
    positions; ``bus_times``: time the samples and switches on the CAN bus (``BusMonitor``)
    instead of by the bridge's stamps. The stack and the client stop on return or error."""
    if measure not in MEASURES:
        raise ValueError(f"measure must be one of {MEASURES}, got {measure!r}")
    from ff_executor.bringup.stack import Stack
    from ff_executor.ros.client import StackClient

    env = envelope or ex.envelope
    if env is None:
        raise ValueError("run_on_stack needs the envelope the excitation was designed for")
    opts = identification_options(true_params, q_start=q_start, friction=friction, run_dir=run_dir,
                                  rt_priority=rt_priority, setpoint_timing=setpoint_timing, envelope=env)
    t0 = time.monotonic()
    with Stack(opts, log=stack_log or (lambda s: None)) as stack:
        bus = bus_monitor(stack) if bus_times else None
        client = StackClient(stack.env, "ff_identify")
        try:
            records, meta = identify_runs(client, ex, stack_q_resolution(base), env, bus=bus, log=log,
                                          measure=measure)
        finally:
            client.close()
            if bus is not None:
                bus.close()
    meta["wall_s"] = time.monotonic() - t0
    if friction:
        meta["friction_mismatch"] = dict(friction)
    return records, meta


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Console script ``ff-identify`` (see ``ff_planner.cli.identify``), ``--sim`` on the stack."""
    return cli.main(argv, sim_runner=run_on_stack)


if __name__ == "__main__":
    sys.exit(main())

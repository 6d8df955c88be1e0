"""The simulated arm (the plant) that the emulated EPOS drives push current into.

One model in the suite: the plant integrates with the PLANNER's model, the ``advance`` of the
model's ``ff_planner.model.registry.model_spec`` (``arm1dof``: 1-DOF arm, ``scara2``: 2-DOF
SCARA), but with its OWN parameters (the "true" friction), so tests can make the real arm
differ from the model the planner believed.

Time is ``time.monotonic_ns()`` unless a clock is given. The state is advanced to the instant
someone sets a current or asks for the state: a current change takes effect at the instant it is
set (the drive calls ``set_current`` with the frame's arrival time), and between changes the
model is stepped in sub-steps of at most ``step`` s (default 0.1 ms), or in one step where the
model's ``advance`` is exact over any interval (the 1-DOF arm's Eq. 9; ``advance_exact``): a plant
that fell behind, or replays a late change, then catches up in microseconds. ``start_clock(period)``
runs the plant on its own thread, advancing it to a little before now every ``period`` s, so that
a caller (a CAN callback) only ever integrates the last few ms, however long the rig was idle.
A state asked for at an instant the plant has already passed (a drive process that handles a
SYNC later than the clock's lag samples at that SYNC's bus instant) is computed from the plant's
history — the latest kept state at or before it, then forward through the current changes since
— without moving the plant: a sample is the state at its instant however late it is taken, as a
real drive latches its encoder at the SYNC. Thread-safe (one lock). Units: rad, rad/s, A, s.

``set_friction(FrictionMismatch(...))`` (1-DOF arm only) gives the arm friction that is not
Eq. 9 — a Stribeck rise of the Coulomb level at low speed, a Coulomb level that varies with
position (``ff_planner.identify.measure.FrictionMismatch``): each sub-step is then the exact
Eq. 9 motion with the Coulomb level of the sub-step's start state, as the offline measurement
simulates it, so that identification on the stack can be tested for honesty.

A drive's current law (``set_law``: its velocity loop braking on a stop ramp, as an EPOS4 runs it
in firmware) is evaluated by the plant itself every ``LAW_PERIOD_NS`` of plant time, however late
the drive's own thread runs: a starved Python thread must not leave a braking current on after
the arm has stopped (it would drive the arm back the other way).
"""
from __future__ import annotations

import bisect
import functools
import inspect
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np

from ff_planner.identify.measure import FrictionMismatch, advance_mismatch
from ff_planner.model.params import Arm1DofParams, ParameterError, Params
from ff_planner.model.registry import model_spec

__all__ = ["AdvanceFn", "ArmState", "CurrentLaw", "FrictionMismatch", "JointPort", "Params", "SimArm", "joint_param",
           "mismatch_advance", "planner_advance"]

#: advance(params, q, qd, currents, dt) -> (q, qd): per-joint arrays of shape (n_joints,),
#: rad, rad/s, A, s (the registry's convention).
AdvanceFn = Callable[..., tuple[np.ndarray, np.ndarray]]


def planner_advance(params: Params) -> AdvanceFn:
    """The planner's one-step model for the parameters' model (``model_spec(params.model)``)."""
    # the models compile with numba: imported when a plant is built, not with this module

    return model_spec(params.model).advance


def substepping_advance(advance: AdvanceFn, step: float) -> Optional[AdvanceFn]:
    """``advance`` taking any ``dt`` in compiled sub-steps of ``step`` s, when the model's advance
    sub-steps itself (a keyword ``h``, e.g. the SCARA's): the same steps (``step`` from the
    interval's start, the last one shorter) as calling it once per step from Python, without a
    Python call per 0.1 ms (which cost the 2-DOF plant ~17 % of a core per simulated second,
    and seconds of catch-up after a stall); None otherwise."""
    try:
        params = inspect.signature(advance).parameters
    except (TypeError, ValueError):
        return None
    if "h" not in params or params["h"].kind is not inspect.Parameter.KEYWORD_ONLY:
        return None
    return functools.partial(advance, h=float(step))


def mismatch_advance(mismatch: FrictionMismatch, step: Optional[float] = None) -> AdvanceFn:
    """A 1-DOF one-step model whose Coulomb level is ``mismatch.coulomb(pc, q, q̇)`` at the start
    of each sub-step of ``step`` s (default ``mismatch.step``), the rest exact Eq. 9 (pv, pt, J,
    kt, n of the parameters); it takes any ``dt`` and sub-steps inside (compiled)."""
    mismatch.validate()

    def advance(params: Params, q: np.ndarray, qd: np.ndarray, currents: np.ndarray,
                dt: float) -> tuple[np.ndarray, np.ndarray]:
        assert isinstance(params, Arm1DofParams)
        q1, v1 = advance_mismatch(params, mismatch, float(q[0]), float(qd[0]), float(currents[0]), dt, step)
        return np.array([q1]), np.array([v1])

    return advance


def joint_param(params: Params, key: str, joint: int) -> float:
    """A per-joint parameter of joint ``joint`` (0-based): ``key`` on a 1-joint model (``n``,
    ``kt``, ``i_max``), ``key`` + joint number on a multi-joint one (``n1``, ``kt2``, ...)."""
    if not 0 <= joint < params.n_joints:
        raise ParameterError(f"joint index must be 0..{params.n_joints - 1}, got {joint}")
    return float(getattr(params, key if params.n_joints == 1 else f"{key}{joint + 1}"))


@dataclass(frozen=True)
class ArmState:
    """Ground truth at ``t_ns`` (monotonic ns): joint angles (rad), rates (rad/s), currents (A)."""

    t_ns: int
    q: tuple[float, ...]
    qd: tuple[float, ...]
    current: tuple[float, ...]


#: ns: a current change asked for this much before the plant's time is rewound: the plant goes back
#: to its state before that instant and integrates again with the change where it belongs (a real
#: drive's timing does not depend on when a process gets the CPU; the simulated one's should not)
LATE_NS = 1_000
#: ns, the period on which the plant evaluates a drive's current law (``set_law``): a velocity
#: loop in the drive's firmware (an EPOS4's runs at 2.5 kHz)
LAW_PERIOD_NS = 400_000
#: A drive's current law: (t ns, q rad, qd rad/s) of its joint -> current A
CurrentLaw = Callable[[int, float, float], float]
#: ns: how far back the plant can rewind (its history); a change older than this starts late, at
#: the plant's time, and is counted in ``late_changes``
REWIND_NS = 2_000_000_000
#: ns between the snapshots a rewind keeps while it replays (without them, every read of the
#: replayed span integrated from the rewind's start: a drive process that fell behind then paid
#: O(its lag) per CAN frame, and fell further behind)
REPLAY_SNAP_NS = 20_000_000


@dataclass(frozen=True)
class _Snapshot:
    t_ns: int
    q: np.ndarray
    qd: np.ndarray
    i: np.ndarray


class SimArm:
    """Joint state of a 1-DOF arm or 2-DOF SCARA under piecewise-constant motor currents."""

    def __init__(self, params: Params, q0: Sequence[float] | float = 0.0,
                 qd0: Sequence[float] | float | None = None, *, step: float = 1e-4,
                 advance: Optional[AdvanceFn] = None,
                 clock: Callable[[], int] = time.monotonic_ns) -> None:
        if not step > 0.0:
            raise ParameterError(f"physics step must be > 0 s, got {step}")
        self.params = params
        self.n_joints = params.n_joints
        self.step = float(step)
        self._advance = advance if advance is not None else planner_advance(params)
        self._own_advance = self._advance
        # an advance exact over any interval (the 1-DOF Eq. 9 motion) needs no sub-steps
        self._own_any_dt = advance is None and model_spec(params.model).advance_exact
        if advance is None and not self._own_any_dt:
            sub = substepping_advance(self._advance, self.step)
            if sub is not None:
                self._advance = self._own_advance = sub
                self._own_any_dt = True
        self._any_dt = self._own_any_dt
        self.friction: Optional[FrictionMismatch] = None    # None: the model's Eq. 9
        self._clock = clock
        self._lock = threading.Lock()
        self._q, self._qd = self._vec(q0, "q0"), self._vec(0.0 if qd0 is None else qd0, "qd0")
        self._i = np.zeros(self.n_joints)
        self._t_ns = clock()
        self._ticker: Optional[threading.Thread] = None
        self._tick_stop = threading.Event()
        self._lag_ns = 0           # while the own clock runs: how far behind now readers look
        self.late_changes = 0      # current changes older than the history: started late
        self.late_max_ns = 0       # ... the largest such lateness (ns)
        self.rewound_changes = 0   # current changes the plant had passed, put in their place
        self.rewound_max_ns = 0    # ... the largest rewind (ns)
        self.stale_reads = 0       # states asked for before the history: the oldest one given
        # the last state read from the history (every drive samples the same SYNC instant): valid
        # while the history is not rewritten (a rewind, or forgetting it)
        self._history_epoch = 0
        self._last_past: Optional[tuple[int, int, ArmState]] = None    # (epoch, t ns, state)
        self._laws: dict[int, CurrentLaw] = {}                # joint -> a drive's current law
        self._snaps: deque[_Snapshot] = deque()              # plant states, oldest first
        self._changes: deque[tuple[int, int, float]] = deque()   # (t ns, joint, A) since the oldest
        self._snapshot()
        self.warm_up_s = self._warm_up()

    def _warm_up(self) -> float:
        """One sub-step of the model from the initial state, result discarded: a model compiled
        on first call (numba, e.g. the SCARA's: 25 s on a loaded 2-core machine with a cold cache)
        compiles or loads here, in the caller's thread, not on the plant's first tick under its
        lock, where every CAN frame that samples the arm would wait for it. Returns seconds."""
        t = time.perf_counter()
        self._advance(self.params, self._q.copy(), self._qd.copy(), np.zeros(self.n_joints), self.step)
        return time.perf_counter() - t

    # -- own clock -----------------------------------------------------------------------------
    def start_clock(self, period: float = 0.002, lag: float = 0.01) -> None:
        """Advance the plant to ``lag`` s before now every ``period`` s, on a thread of its own
        (idempotent).

        The lag keeps the clock behind the CAN frames still being handled: a current change
        stamped with its frame's arrival time then still lands at that instant (the state can
        only move forward). Without it, a tick between a frame's arrival and its handling would
        apply the switch at the tick, tens of µs to ms late."""
        if not period > 0.0 or not lag >= 0.0:
            raise ParameterError(f"clock period must be > 0 s and lag >= 0 s, got {period}, {lag}")
        lag_ns = int(lag * 1e9)
        if self._ticker is not None and self._ticker.is_alive():
            return
        self._tick_stop.clear()
        self._lag_ns = lag_ns

        def run() -> None:
            while not self._tick_stop.wait(period):
                with self._lock:
                    self._advance_to(self._clock() - lag_ns)
                    self._snapshot()

        self._ticker = threading.Thread(target=run, name="sim-arm-clock", daemon=True)
        self._ticker.start()

    def stop_clock(self) -> None:
        """Stop the plant's own thread (the state is then advanced on demand only)."""
        self._tick_stop.set()
        if self._ticker is not None:
            self._ticker.join(timeout=2.0)
            self._ticker = None
        self._lag_ns = 0

    # -- helpers -------------------------------------------------------------------------------
    def _vec(self, x: Sequence[float] | float, name: str) -> np.ndarray:
        a = np.atleast_1d(np.asarray(x, dtype=float)).copy()
        if a.size == 1 and self.n_joints > 1 and np.ndim(x) == 0:
            a = np.full(self.n_joints, float(a[0]))
        if a.shape != (self.n_joints,) or not np.all(np.isfinite(a)):
            raise ParameterError(f"{name} must be {self.n_joints} finite value(s), got {x!r}")
        return a

    def _integrate(self, dt: float) -> None:
        self._q, self._qd = self._integrate_from(self._q, self._qd, self._i, dt, self._t_ns)

    def _integrate_from(self, q: np.ndarray, qd: np.ndarray, i: np.ndarray,
                        dt: float, t_ns: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(q rad, qd rad/s) after ``dt`` s of currents ``i`` (A) from (q, qd) at plant time
        ``t_ns``; q and qd are not changed. A joint under a current law (``set_law``) takes the
        law's current every ``LAW_PERIOD_NS`` (written into ``i``)."""
        q, qd = np.array(q, dtype=float), np.array(qd, dtype=float)
        if not self._laws:
            return self._run(q, qd, i, dt)
        t, end = int(t_ns), int(t_ns) + int(round(dt * 1e9))
        while t < end:
            for j, law in self._laws.items():
                i[j] = float(law(t, float(q[j]), float(qd[j])))
            nxt = min(end, (t // LAW_PERIOD_NS + 1) * LAW_PERIOD_NS)
            q, qd = self._run(q, qd, i, (nxt - t) * 1e-9)
            t = nxt
        return q, qd

    def _run(self, q: np.ndarray, qd: np.ndarray, i: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``dt`` s of constant currents ``i`` from (q, qd), in the model's steps."""
        p = self.params
        while dt > 0.0:
            h = dt if self._any_dt else min(self.step, dt)
            q1, qd1 = self._advance(p, q.copy(), qd.copy(), i.copy(), h)
            q[:], qd[:] = q1, qd1
            dt -= h
        return q, qd

    def _snapshot(self) -> None:
        """Keep the state at the plant's time; forget what is older than ``REWIND_NS``."""
        self._snaps.append(_Snapshot(self._t_ns, self._q.copy(), self._qd.copy(), self._i.copy()))
        oldest = self._t_ns - REWIND_NS
        while len(self._snaps) > 1 and self._snaps[1].t_ns <= oldest:
            self._snaps.popleft()
        while self._changes and self._changes[0][0] < self._snaps[0].t_ns:
            self._changes.popleft()

    def _forget_history(self) -> None:
        """The trajectory so far can no longer be replayed (new state, parameters or law)."""
        self._history_epoch += 1
        self._snaps.clear()
        self._changes.clear()
        self._snapshot()

    def _current_at(self, t_ns: int, joint: int) -> Optional[float]:
        """A, the current motor ``joint`` carried at ``t_ns`` by the history (its latest change at or
        before it, else the oldest snapshot's); None where the history does not reach back."""
        if not self._snaps or t_ns < self._snaps[0].t_ns:
            return None
        for tc, j, c in reversed(self._changes):
            if j == joint and tc <= t_ns:
                return c
        return float(self._snaps[0].i[joint])

    def _advance_keeping(self, t_ns: int) -> None:
        """``_advance_to`` with a snapshot every ``REPLAY_SNAP_NS`` of plant time on the way (a
        replay keeps the history dense: a later read of the past integrates at most that long)."""
        while t_ns - self._t_ns > REPLAY_SNAP_NS:
            self._advance_to(self._t_ns + REPLAY_SNAP_NS)
            self._snapshot()
        self._advance_to(t_ns)

    def _rewind(self, t_ns: int, joint: int, current: float) -> bool:
        """Put a change at ``t_ns`` < the plant's time in its place: back to the latest state at or
        before it, then forward again through every change since, the new one included. False if
        the history does not reach back that far."""
        if self._t_ns - t_ns > REWIND_NS:
            return False
        k = bisect.bisect_right(self._snaps, t_ns, key=lambda sn: sn.t_ns) - 1
        if k < 0:
            return False
        t_end, snap = self._t_ns, self._snaps[k]
        self._history_epoch += 1
        replay = [c for c in self._changes if c[0] > snap.t_ns]
        pos = bisect.bisect_right([c[0] for c in replay], t_ns)
        replay.insert(pos, (t_ns, joint, float(current)))
        while len(self._snaps) > k + 1:
            self._snaps.pop()
        while self._changes and self._changes[-1][0] > snap.t_ns:
            self._changes.pop()
        self._q, self._qd, self._i = snap.q.copy(), snap.qd.copy(), snap.i.copy()
        self._t_ns = snap.t_ns
        for t, j, c in replay:
            self._advance_keeping(t)
            self._i[j] = c
            self._changes.append((t, j, c))
            self._snapshot()
        self._advance_keeping(t_end)
        self._snapshot()
        return True

    def _advance_to(self, t_ns: int) -> None:
        if t_ns > self._t_ns:                 # events arriving a hair out of order: no time travel
            self._integrate((t_ns - self._t_ns) * 1e-9)
            self._t_ns = t_ns

    # -- public API ----------------------------------------------------------------------------
    def now(self) -> int:
        """The plant's clock (ns)."""
        return self._clock()

    def horizon(self) -> int:
        """The latest instant (ns, plant clock) a reader may look at without getting ahead of the
        CAN frames still being handled: now minus the own clock's lag (now when it does not run)."""
        return self._clock() - self._lag_ns

    def set_current(self, joint: int, current: float, t_ns: Optional[int] = None) -> None:
        """Motor ``joint`` (0-based) carries ``current`` A from ``t_ns`` (default: now) on."""
        if not 0 <= joint < self.n_joints:
            raise ParameterError(f"joint index must be 0..{self.n_joints - 1}, got {joint}")
        with self._lock:
            if t_ns is not None and self._t_ns - t_ns > LATE_NS:
                if not self._laws and self._current_at(t_ns, joint) == float(current):
                    return          # the joint carries it already: the trajectory stays as it is
                if self._rewind(t_ns, joint, current):
                    self.rewound_changes += 1
                    self.rewound_max_ns = max(self.rewound_max_ns, self._t_ns - t_ns)
                    return
                if float(current) != self._i[joint]:
                    self.late_changes += 1
                    self.late_max_ns = max(self.late_max_ns, self._t_ns - t_ns)
            self._advance_to(self._clock() if t_ns is None else t_ns)
            self._i[joint] = float(current)
            self._changes.append((self._t_ns, joint, float(current)))
            self._snapshot()

    def set_law(self, joint: int, law: Optional[CurrentLaw], t_ns: Optional[int] = None) -> None:
        """From ``t_ns`` (default now) motor ``joint`` carries the current ``law(t ns, q rad, qd
        rad/s)`` A, evaluated by the plant every ``LAW_PERIOD_NS`` (a drive's firmware loop, e.g.
        braking on a stop ramp); None: the law ends, the current stays at its last value until
        ``set_current``. The history before it cannot be replayed."""
        if not 0 <= joint < self.n_joints:
            raise ParameterError(f"joint index must be 0..{self.n_joints - 1}, got {joint}")
        with self._lock:
            self._advance_to(self._clock() if t_ns is None else int(t_ns))
            if law is None:
                self._laws.pop(joint, None)
            else:
                self._laws[joint] = law
                self._i[joint] = float(law(self._t_ns, float(self._q[joint]), float(self._qd[joint])))
            self._forget_history()

    def has_law(self, joint: int) -> bool:
        """Whether motor ``joint`` is under a drive's current law now."""
        return joint in self._laws

    def state(self, t_ns: Optional[int] = None) -> ArmState:
        """Ground truth at ``t_ns``. Default: the ``horizon()``, or the plant's time where that is
        later (reading the state never moves the plant past a current change still in flight).
        A given instant the plant has passed is read from its history (``_past_state``; the
        plant does not move); one older than the history gives the oldest state kept and is
        counted in ``stale_reads``. ``ArmState.t_ns`` says which instant it is."""
        with self._lock:
            t = max(self.horizon(), self._t_ns) if t_ns is None else int(t_ns)
            if t < self._t_ns:
                return self._past_state(t)
            self._advance_to(t)
            return ArmState(self._t_ns, tuple(map(float, self._q)), tuple(map(float, self._qd)),
                            tuple(map(float, self._i)))

    def _past_state(self, t_ns: int) -> ArmState:
        """The state at ``t_ns`` < the plant's time: from the latest snapshot at or before it,
        forward through the changes after that snapshot up to ``t_ns`` (a change at ``t_ns``
        itself included: it sets the current, not the position); the plant is left as it is."""
        last = self._last_past
        if last is not None and last[0] == self._history_epoch and last[1] == t_ns:
            return last[2]
        state = self._integrate_past(t_ns)
        if state.t_ns == t_ns:          # not a stale read (older than the history)
            self._last_past = (self._history_epoch, int(t_ns), state)
        return state

    def _integrate_past(self, t_ns: int) -> ArmState:
        k = bisect.bisect_right(self._snaps, t_ns, key=lambda sn: sn.t_ns) - 1
        if k < 0:
            self.stale_reads += 1
            k, t_ns = 0, self._snaps[0].t_ns
        snap = self._snaps[k]
        between = []                  # the changes in (snapshot, t_ns], newest first
        for change in reversed(self._changes):
            if change[0] <= snap.t_ns:
                break
            if change[0] <= t_ns:
                between.append(change)
        q, qd, i = snap.q.copy(), snap.qd.copy(), snap.i.copy()
        t = snap.t_ns
        for tc, j, c in reversed(between):
            q, qd = self._integrate_from(q, qd, i, (tc - t) * 1e-9, t)
            t = tc
            i[j] = c
        q, qd = self._integrate_from(q, qd, i, (t_ns - t) * 1e-9, t)
        return ArmState(int(t_ns), tuple(map(float, q)), tuple(map(float, qd)), tuple(map(float, i)))

    def joint(self, joint: int, t_ns: Optional[int] = None) -> tuple[float, float, float]:
        """(q rad, qd rad/s, current A) of one joint at ``t_ns``."""
        s = self.state(t_ns)
        return s.q[joint], s.qd[joint], s.current[joint]

    def reset(self, q0: Sequence[float] | float = 0.0, qd0: Sequence[float] | float | None = None,
              params: Optional[Params] = None) -> None:
        """Put the arm back at (q0, qd0) with zero current, now; optionally new true parameters."""
        with self._lock:
            if params is not None:
                if type(params) is not type(self.params):
                    raise ParameterError("reset cannot change the arm model; make a new SimArm")
                self.params = params
            self._q, self._qd = self._vec(q0, "q0"), self._vec(0.0 if qd0 is None else qd0, "qd0")
            self._i[:] = 0.0
            self._laws.clear()
            self._t_ns = self._clock()
            self._forget_history()

    def set_params(self, params: Params) -> None:
        """Change the true parameters from now on (state kept; same model type only)."""
        if type(params) is not type(self.params):
            raise ParameterError("cannot change the arm model of a running SimArm")
        with self._lock:
            self._advance_to(self._clock())
            self.params = params
            self._forget_history()

    def set_friction(self, mismatch: Optional[FrictionMismatch]) -> None:
        """From now on, friction that is not Eq. 9 (1-DOF arm only; None or an inactive
        mismatch: back to the model's Eq. 9)."""
        active = mismatch is not None and mismatch.active
        if active and not isinstance(self.params, Arm1DofParams):
            raise ParameterError("friction that is not Eq. 9 is offered for the 1-DOF arm only")
        adv = mismatch_advance(mismatch, self.step) if active and mismatch is not None else self._own_advance
        with self._lock:
            self._advance_to(self._clock())
            self._advance = adv
            self._any_dt = True if active else self._own_any_dt     # mismatch_advance sub-steps itself
            self.friction = mismatch if active else None
            self._forget_history()

    def port(self, joint: int) -> "JointPort":
        """The connection one drive uses to push current into motor ``joint``."""
        return JointPort(self, joint)


@dataclass(frozen=True)
class JointPort:
    """A drive's view of its motor: set current at an instant, sample the joint at an instant."""

    arm: SimArm
    joint: int

    def set_current(self, current: float, t_ns: int) -> None:
        self.arm.set_current(self.joint, current, t_ns)

    def set_law(self, law: Optional[CurrentLaw], t_ns: int) -> None:
        """The drive's current law from ``t_ns`` on (None: ended); see ``SimArm.set_law``."""
        self.arm.set_law(self.joint, law, t_ns)

    def sample(self, t_ns: int) -> tuple[float, float, float]:
        """(q rad, qd rad/s, current A) of the joint at ``t_ns``."""
        return self.arm.joint(self.joint, t_ns)

    @property
    def gear_ratio(self) -> float:
        """Joint angle = motor angle / gear_ratio."""
        return joint_param(self.arm.params, "n", self.joint)

    @property
    def torque_constant(self) -> float:
        """Nm/A of the joint's motor."""
        return joint_param(self.arm.params, "kt", self.joint)

"""The identification runner's decisions without a stack: a run whose reach from where the arm
rests leaves the envelope is refused before anything is sent; a run that moved the arm but gave
no data is not repeated from the wrong place; the bus says why a run gave no data; the bridge's
guard envelope lies outside the identification envelope."""
from __future__ import annotations

from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import pytest

from ff_executor.bringup.identify import (GUARD_MARGIN, GUARD_SPEED, StackFault, bus_timing, guard_envelope,
                                          identify_runs, stack_q_resolution, switch_changes)
from ff_planner.identify import Envelope, design_excitation
from ff_planner.identify.sampling import sample_params
from ff_planner.model.params import preset

BASE = preset("table2")
ENV = Envelope(-1.0, 1.0, 3.0, i_max=3.0)
Q_RES = stack_q_resolution(BASE)


@dataclass
class FakeProbe:
    """Rest positions in order (one per ``wait_at_rest`` call), no faults."""

    rests: list[float]
    last_rest: float | None = None
    resets: int = 0

    def check_stack(self) -> None:
        pass

    def check_drive(self) -> None:
        pass

    def sim_late_switches(self, fresh: float = 0.0) -> None:
        return None

    def fault_reset(self) -> str:
        self.resets += 1
        return "cleared"

    def wait_at_rest(self, q_res: float) -> float:
        self.last_rest = self.rests.pop(0)
        return self.last_rest


@dataclass
class FakeClient:
    """Executes a run on the exact model from the goal's start position; the runs listed in
    ``fail`` (1-based call numbers) move the arm but do not complete."""

    fail: set[int] = field(default_factory=set)
    calls: list[float] = field(default_factory=list)

    def execute(self, msg, timeout: float):
        from ff_msgs_py.convert import msg_to_profile

        prof = msg_to_profile(msg)
        q0 = float(msg.q0[0])
        self.calls.append(q0)
        t = np.arange(0.0, prof.tf, 0.01)
        q, qd = sample_params(BASE, prof, q0, t)
        joints = SimpleNamespace(arrays=lambda: (t + 100.0, q.reshape(-1, 1), qd.reshape(-1, 1),
                                                 np.array([prof.current_at(x) for x in t]).reshape(-1, 1)))
        ok = len(self.calls) not in self.fail
        return SimpleNamespace(joints=joints, succeeded=ok, profile_start=100.0,
                               switch_delays=[0.0] * len(switch_changes(prof.currents)),
                               result=SimpleNamespace(message="done" if ok else "aborted: safe state"))


def test_a_run_that_could_leave_the_envelope_from_where_the_arm_rests_is_refused_and_nothing_is_sent():
    ex = design_excitation(BASE, ENV, 0.0, levels=[1.0])
    lo, hi = ex.runs[0].reach
    assert lo <= 0.0 < hi                       # the design's reach: the first run goes up
    client = FakeClient()
    with pytest.raises(RuntimeError, match="nothing was sent") as info:
        identify_runs(client, ex, Q_RES, ENV, probe=FakeProbe([1.0 - 0.5 * hi]), log=lambda s: None)
    assert client.calls == [] and "outside the envelope" in str(info.value)


def test_a_run_that_moved_the_arm_without_data_is_left_out_and_the_next_starts_where_it_ended():
    ex = design_excitation(BASE, ENV, 0.0, levels=[1.0, 2.0])
    r1 = ex.runs[0]
    # run 1 moves the arm to its end and fails; the arm rests there for run 2, and so on
    rests = [0.0, r1.q_end, r1.q_end] + [r.q0 for r in ex.runs[2:]]
    probe = FakeProbe(rests)
    client = FakeClient(fail={1})
    records, meta = identify_runs(client, ex, Q_RES, ENV, probe=probe, log=lambda s: None)
    assert meta["lost_runs"] == [1] and len(records) == len(ex.runs) - 1
    assert client.calls[:2] == [0.0, r1.q_end]             # not run 1 again from its end
    assert probe.resets == 1 and "safe state" in meta["stack_faults"][0]


def test_a_run_that_gave_no_data_and_left_the_arm_where_it_was_is_run_again():
    ex = design_excitation(BASE, ENV, 0.0, levels=[1.0])
    probe = FakeProbe([0.0, 0.0, 0.0, ex.runs[1].q0])
    client = FakeClient(fail={1})
    records, meta = identify_runs(client, ex, Q_RES, ENV, probe=probe, log=lambda s: None)
    assert meta["lost_runs"] == [] and len(records) == 2 and client.calls[:2] == [0.0, 0.0]


class _Bus:
    def __init__(self, changes, instants):
        self._changes, self._instants, self.unpaired = changes, instants, 7

    def current_changes(self, t_from, t_to, latched=None):
        return list(self._changes)

    def sample_instants(self, stamps):
        return self._instants(np.asarray(stamps, float))


def test_the_bus_says_why_a_run_gave_no_data():
    ex = design_excitation(BASE, ENV, 0.0, levels=[1.0])
    prof = ex.runs[0].profile
    a, b = (float(x) for x in prof.currents[:, 0])
    stamps = np.arange(0.0, 1.0, 0.01)
    with pytest.raises(StackFault, match="then 0"):              # never back to zero
        bus_timing(_Bus([(0.0, a), (0.3, b)], lambda s: s), stamps, prof, 0.0)
    with pytest.raises(StackFault, match="not those of the run"):
        bus_timing(_Bus([(0.0, a + 0.5), (0.3, b), (0.6, 0.0)], lambda s: s), stamps, prof, 0.0)
    def half(s):
        return np.where(np.arange(s.size) % 3 == 0, s, np.nan)      # a third placed
    with pytest.raises(StackFault, match="could be placed"):
        bus_timing(_Bus([(0.0, a), (0.3, b), (0.6, 0.0)], half), stamps, prof, 0.0)
    def most(s):
        return np.where(np.arange(s.size) % 3 == 0, np.nan, s)      # two thirds placed: data
    t, applied, keep = bus_timing(_Bus([(0.0, a), (0.3, b), (0.6, 0.0)], most), stamps, prof, 0.0)
    assert keep.sum() == t.size == 66 and applied.currents[:, 0].tolist() == [a, b]


def test_the_bridge_guard_lies_outside_the_identification_envelope():
    lo, hi, v = guard_envelope(ENV)
    span = ENV.q_max - ENV.q_min
    assert lo == pytest.approx(ENV.q_min - GUARD_MARGIN * span) and hi == pytest.approx(ENV.q_max + GUARD_MARGIN * span)
    assert v == pytest.approx(GUARD_SPEED * ENV.v_max) and lo < ENV.q_min and hi > ENV.q_max and v > ENV.v_max

"""Stop setpoints in SYNC mode: a cancel's zeros (an immediate zero and a zero 1 µs after each
stamp already handed over, all ``last``, as the executor sends them) end on zero current at the
drive, whatever the player's grid estimate does between the profile and the cancel.

The SYNC grid the player predicts (``SyncWatch.grid``) moves by a few µs as SYNCs jitter. The
grid seen when the cancel's zeros are shifted is moved 5 µs earlier here than when the profile
was: a zero that got a shift of its own would then sort before the step it follows by 1 µs, go to
the same SYNC and be sent first, and the drive would latch the step. python-can virtual bus,
simulated EPOS4, no rclpy.
"""
from __future__ import annotations

import time
from typing import Callable, Optional

import pytest

from ff_hwbridge.drive.epos import REFRESH_PERIOD
from tests.ff_hwbridge.drive.test_sync_player import PERIOD, SyncBench
from tests.support.canopen_helpers import waiter

wait_for = waiter(5.0)
P_NS = int(PERIOD * 1e9)


@pytest.fixture
def bench():
    # tolerant of a loaded machine's stalls: these tests are about order, not watchdogs
    b = SyncBench(missed_cycle_tolerance=50, heartbeat_timeout=3.0, feedback_timeout=3.0,
                  sync_timeout=3.0, setpoint_timeout=5.0)
    b.enable()
    yield b
    b.close()


def _drifting_grid(bench: SyncBench, drift_ns: int) -> Callable[[], None]:
    """Freeze the grid the player's phase lock sees; the returned function moves it by
    ``drift_ns`` (the scheduler's own cycle assignment keeps the live grid)."""
    cycle = bench.player._cycle
    assert cycle is not None
    live = cycle.grid()
    assert live is not None                  # the bench is enabled: SYNCs have been seen
    nominal, period = live
    state = {"nominal": nominal}

    def grid() -> Optional[tuple[int, int]]:
        return state["nominal"], period

    cycle.grid = grid           # type: ignore[method-assign]

    def drift() -> None:
        state["nominal"] += drift_ns

    return drift


def _final_raw(bench: SyncBench) -> int:
    log = bench.drive.setpoint_log()
    return log[-1].raw if log else 0


def _drive_latched_up_to(bench: SyncBench, applied: list) -> bool:
    """The simulated drive has logged a latch at or after the last SYNC (bus wall ns) the player
    reports a setpoint applied at: the player learns of a latch from the bus, the drive's thread
    logs it on its own schedule, and on a loaded machine the drive may lag the report."""
    last_sync = max(a.sent_ns for a in applied)
    log = bench.drive.setpoint_log()
    return bool(log) and log[-1].wall_ns >= last_sync


def _step_stamps(bench: SyncBench) -> list[int]:
    """Stamps of a profile that starts 0.2 periods past a SYNC, 30 cycles ahead (the switch
    times on the SYNC period's grid, as the planner's switch_grid gives them)."""
    grid = bench.player.sync_grid()
    assert grid is not None
    nominal, period = grid
    base = nominal + 30 * period + int(0.2 * period)
    return [base + k * period for k in range(3)]


def test_cancel_zeros_after_the_profile_end_on_zero_current(bench):
    drift = _drifting_grid(bench, -5_000)
    t = _step_stamps(bench)
    pid = "cancelled-profile"
    bench.player.submit(t[0], [1.1], seq=0, profile_id=pid)
    bench.player.submit(t[1], [2.27], seq=1, profile_id=pid)
    drift()
    # the executor's cancel: zero now (before the steps), a zero 1 µs after each pending step
    bench.player.submit(t[0] - 5 * P_NS, [0.0], seq=3, profile_id=pid, last=True)
    bench.player.submit(t[0] + 1_000, [0.0], seq=4, profile_id=pid, last=True)
    bench.player.submit(t[1] + 1_000, [0.0], seq=5, profile_id=pid, last=True)
    assert wait_for(lambda: bench.player.pending == 0)
    got: list = []
    assert wait_for(lambda: got.extend(bench.player.take_applied()) or len(got) == 5)
    by_seq = {a.seq: a for a in got}
    # each zero takes effect at or after the step it follows, never before
    assert by_seq[4].sent_ns >= by_seq[0].sent_ns and by_seq[5].sent_ns >= by_seq[1].sent_ns, got
    assert wait_for(lambda: _drive_latched_up_to(bench, got))
    assert _final_raw(bench) == 0, [r.raw for r in bench.drive.setpoint_log()[-6:]]
    assert bench.master.applied_currents()[0] == 0.0
    assert not bench.master.latched


def test_a_zero_of_another_profile_stays_after_the_step_it_follows(bench):
    """The order of stamps is kept whatever the phase bookkeeping: a zero stamped 1 µs after a
    step of a different profile (its own, fresh shift onto the grid) still follows it."""
    drift = _drifting_grid(bench, -5_000)
    t = _step_stamps(bench)
    bench.player.submit(t[1], [2.27], seq=0, profile_id="a")
    drift()
    bench.player.submit(t[1] + 1_000, [0.0], seq=0, profile_id="b", last=True)
    assert wait_for(lambda: bench.player.pending == 0)
    got: list = []
    assert wait_for(lambda: got.extend(bench.player.take_applied()) or len(got) == 2)
    assert wait_for(lambda: _drive_latched_up_to(bench, got))
    assert _final_raw(bench) == 0, [r.raw for r in bench.drive.setpoint_log()[-4:]]


def test_with_an_external_player_the_master_sends_no_current_and_tells_the_gate_first():
    """``external_player``: the master's RPDOs carry 0 A only, no per-cycle repeat for an
    enabled drive of its own (the player's), and the gate (what the player may send) changes
    before the safe-state reaction."""
    b = SyncBench(heartbeat_timeout=3.0, feedback_timeout=3.0, sync_timeout=3.0, rpdo_timeout_ms=0)
    try:
        b.enable()
        # no player feeds the enabled drive here: its interpolation supervision would fault it
        b.drive.interpolation_supervision = False
        m = b.master
        seen: list[list] = []
        m.gate_listener = lambda: seen.append([m.gate(), m.applied_currents()[0], m.latched])
        m.external_player = True
        assert m.gate() == [(0x000F, True)]
        m.command_currents([1.0])
        time.sleep(3 * REFRESH_PERIOD)
        assert all(r.raw == 0 for r in b.drive.setpoint_log())          # no current from here
        tx = m.rpdo_marks()[0]
        time.sleep(3 * REFRESH_PERIOD)
        assert m.rpdo_marks()[0] == tx                                   # no refresh of its own
        m.trip("test reaction")
        assert seen and seen[0][0] == [(0x000F, False)] and seen[0][2]  # gate closed first
    finally:
        b.master.external_player = False
        b.master.gate_listener = None
        b.close()

"""GridPlacement: one shift onto the SYNC grid per profile run (kept past its ``last`` for a
cancel's zeros, taken anew at the next seq 0), and shifted stamps that keep the order of the
stamps whatever shift each got. Pure computation on a hand-set grid."""
from __future__ import annotations

import numpy as np

from ff_hwbridge.drive.placement import GRID_TOLERANCE, GridPlacement

P = 10_000_000          # ns, the SYNC period


class Grid:
    def __init__(self, nominal: int = 1_000 * P) -> None:
        self.nominal = nominal

    def __call__(self) -> tuple[int, int]:
        return self.nominal, P


def test_a_run_keeps_its_shift_past_last_and_the_next_run_takes_a_new_one():
    grid = Grid()
    g = GridPlacement(grid)
    base = grid.nominal + 30 * P + 2 * P // 10                  # 0.2 periods past a SYNC
    run1 = [g.place(base + k * P, "p", k) for k in range(3)]
    assert [s - (base + k * P) for k, s in enumerate(run1)] == [8 * P // 10] * 3   # onto the grid
    grid.nominal -= 5_000                                       # the grid estimate moves
    # a cancel's zeros after the run's last: the run's shift, not one of their own
    assert g.place(base + P + 1_000, "p", 4) == base + P + 1_000 + 8 * P // 10
    base2 = base + 50 * P + 7 * P // 10
    run2 = [g.place(base2 + k * P, "p", k) for k in range(2)]   # seq 0: a new run
    assert run2[0] % P == grid.nominal % P and run2[1] - run2[0] == P
    assert g.place(base2, "", 0) >= run2[0]                     # no profile id: no shift, in order


def test_a_stamp_on_the_grid_stays_on_its_sync_when_the_estimate_drifted_by_ns():
    grid = Grid()
    g = GridPlacement(grid)
    stamp = grid.nominal + 20 * P
    grid.nominal += 7 * P - 64                                  # 7 SYNCs later, 64 ns of drift
    assert g.place(stamp, "on-grid", 0) == grid.nominal + 13 * P   # its SYNC, not the one after
    assert g.place(stamp + P // 5, "other", 0) == grid.nominal + 14 * P   # 0.2 P after: the next


def test_shifted_stamps_keep_the_order_of_the_stamps_whatever_the_shifts():
    rng = np.random.default_rng(7)
    grid = Grid()
    g = GridPlacement(grid)
    placed: list[tuple[int, int]] = []
    t = grid.nominal + 10 * P
    for _ in range(2000):
        grid.nominal += int(rng.integers(-20_000, 20_000))     # a jittery grid estimate
        stamp = t + int(rng.integers(-3 * P, 3 * P))            # out of order at times
        pid = f"p{int(rng.integers(0, 4))}"
        seq = int(rng.integers(0, 3))                           # runs start now and then
        s = g.place(stamp, pid, seq)
        assert s >= stamp - P // GRID_TOLERANCE                 # never before its own stamp (but ns)
        # never before a setpoint submitted earlier with a stamp at or before this one
        assert all(s >= ps for pt, ps in placed[-200:] if pt <= stamp)
        placed.append((stamp, s))
        t += int(rng.integers(0, P))

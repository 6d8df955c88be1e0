"""Task grids with ``switch_grid``: gridded requests, refused where the planner places no grid."""
from __future__ import annotations

import pytest

from ff_planner.library.grid import GridError, expand, parse_grid
from ff_planner.library.gridded import GridPlanRequest

BASE = {"model": "arm1dof", "uncertain": ["pc"], "q0": 0.0, "qf": [0.5, 1.0], "tf": 1.0}


def test_switch_grid_makes_gridded_requests():
    grid = expand(parse_grid(dict(BASE, switch_grid=0.001)))
    assert grid.tasks and all(isinstance(t.request, GridPlanRequest) and t.request.grid == 0.001
                              for t in grid.tasks)
    plain = expand(parse_grid(BASE))
    assert all(getattr(t.request, "grid", None) is None for t in plain.tasks)
    assert [t.key for t in grid.tasks] == [t.key for t in plain.tasks]     # same tasks, same keys


@pytest.mark.parametrize("extra, text", [
    (dict(switch_grid=-0.001), "positive"),
    (dict(switch_grid=2.0), "below the shortest move time"),
    (dict(switch_grid=0.001, objective="time-optimal"), "does not place"),
    (dict(switch_grid=0.001, model="scara2", uncertain=["pc1"], q0=[0.0, 0.0], qf=[0.5, 0.0]), "does not place"),
])
def test_bad_switch_grid_is_refused(extra, text):
    with pytest.raises(GridError, match=text):
        parse_grid(dict(BASE, **extra))

"""The motion library: the SQLite store of solved tasks, task grids, warm starts, refusals.

The Dask builder is ``ff_planner.library.build`` (``build_library``); it is not imported here, as
it loads the planner facade and its compiled kernels. ``ff_planner.library.cluster``: the
scheduler address and its TLS certificates.
"""
from ff_planner.library.grid import (
           Grid,
           GridError,
           GridSpec,
           GridTask,
           continuation_tree,
           describe,
           expand,
           load_grid,
           parse_grid,
)
from ff_planner.library.refusal import failure
from ff_planner.library.store import (
           STATUSES,
           LibraryError,
           MotionLibrary,
           MotionRecord,
           canonical_coords,
           params_hash,
           record_from_result,
           task_key,
)
from ff_planner.library.warm import PlanFn, warm_plan

__all__ = ["STATUSES", "Grid", "GridError", "GridSpec", "GridTask", "LibraryError", "MotionLibrary",
           "MotionRecord", "PlanFn", "canonical_coords", "continuation_tree", "describe", "expand", "failure",
           "load_grid", "params_hash", "parse_grid", "record_from_result", "task_key", "warm_plan"]

"""Task grids for motion-library builds: a YAML spec, its expansion into PlanRequests, and the
neighbour (continuation) order in which to solve them.

Grid file (YAML; angles rad, times s)::

    model: arm1dof              # or scara2
    preset: table2              # optional; default = the model's paper table
    params: {pc: 0.2}           # optional overrides of model parameters (SI units)
    objective: robust-derivative
    uncertain: [pv, pc, pt]
    steps: 5                    # optional; default 2 + len(uncertain)
    coast: 0.05
    starts: 50                  # multistart count for cold solves
    seed: 0
    time_budget: 30             # s per task
    tol: 1.0e-6
    q0: 0.0                     # an axis: a number, a list, or {start, stop, step} (stop included)
    qf: {start: 0.5, stop: 1.5, step: 0.25}
    tf: [0.8, 1.0, 1.2]
    switch_grid: 0.001          # s, optional: switch times on the drives' SYNC grid (the robust
                                #    1-DOF plans; what the planner node serves)
    zero_moves: skip            # skip | keep  (tasks with qf == q0)
    max_tasks: 100000
    scheduler: tls://HOST:PORT  # optional: build on this Dask scheduler (ff-library build --scheduler)
    tls_ca_file: ca.pem         # with tls://: the cluster's CA, this client's certificate and key
    tls_cert: client.pem        #    (PEM; relative names are taken from the grid file's folder)
    tls_key: client.key

For scara2, ``q0`` and ``qf`` are lists with one axis per joint, e.g.
``q0: [-0.5, 0.0]`` or ``qf: [{start: 0.3, stop: 0.7, step: 0.1}, 0.0]``.

The grid is the Cartesian product q0 × qf × tf. Tasks that are the same motion shifted in angle
(same :func:`ff_planner.library.store.canonical_coords`) are solved once; the others are stored as
shifted copies. The continuation order (:func:`continuation_tree`) is a breadth-first tree over a
minimum spanning tree of the distinct tasks in grid-step units, rooted at the tree's centre: every
task but the root(s) has a parent one grid step away, solved before it. The tree depends only on
the grid, so a build gives the same results whatever the number of workers or the timing.

No ROS here.
"""
from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence, Union

import numpy as np
import yaml
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from ff_planner.library.cluster import (
    CONFIG_KEYS,
    ClusterError,
    SchedulerSettings,
    parse_address,
    settings_from_mapping,
)
from ff_planner.library.gridded import GridPlanRequest, applies
from ff_planner.library.store import canonical_coords, task_key
from ff_planner.model.params import MODELS, ParameterError, Params, default_params, n_joints, preset
from ff_planner.model.profile import DEFAULT_COAST, OBJECTIVES, PlanningError, PlanRequest

_KEYS = ("model", "preset", "params", "objective", "uncertain", "steps", "coast", "starts", "seed",
         "time_budget", "tol", "q0", "qf", "tf", "zero_moves", "max_tasks", "name", "switch_grid", *CONFIG_KEYS)
_DIGITS = 9


class GridError(ValueError):
    """A grid file that cannot be used; the message names the key and what to change."""


@dataclass
class Axis:
    """The values one grid coordinate takes (rad or s), and its step (0 for a single value)."""

    name: str
    values: list[float]
    step: float

    def __len__(self) -> int:
        return len(self.values)


@dataclass
class GridSpec:
    """A parsed grid file (see module docstring)."""

    model: str
    params: Params
    objective: str
    uncertain: list[str]
    steps: Optional[int]
    coast: float
    starts: int
    seed: int
    time_budget: float
    tol: float
    q0: list[Axis]
    qf: list[Axis]
    tf: Axis
    zero_moves: str = "skip"
    max_tasks: int = 100000
    name: str = ""
    switch_grid: Optional[float] = None    # s; None = switch times anywhere
    scheduler: Optional[SchedulerSettings] = None   # where to build; None = the command line decides

    @property
    def axes(self) -> list[Axis]:
        return [*self.q0, *self.qf, self.tf]

    def size(self) -> int:
        return int(np.prod([len(a) for a in self.axes]))


@dataclass
class GridTask:
    """One task of the grid: its request, key, grid index and canonical coordinates."""

    index: tuple[int, ...]          # position on every axis (q0 joints, qf joints, tf)
    request: PlanRequest
    key: str                        # library task key
    coords: np.ndarray              # canonical coordinates (rad, s)
    rep: int = -1                   # index (in the task list) of the task solved for this motion
    parent: int = -1                # continuation parent (task-list index of a representative), -1 = root
    depth: int = 0


@dataclass
class Grid:
    """The expanded grid: tasks in grid order, the representatives of distinct motions, the tree."""

    spec: GridSpec
    tasks: list[GridTask]
    reps: list[int]                            # task-list indices of distinct motions
    twins: dict[int, list[int]] = field(default_factory=dict)   # rep -> other tasks of the same motion
    children: dict[int, list[int]] = field(default_factory=dict)
    roots: list[int] = field(default_factory=list)
    skipped_zero: int = 0

    def order(self) -> list[int]:
        """Representatives in breadth-first continuation order (parents before children)."""
        out: list[int] = []
        queue = deque(self.roots)
        while queue:
            i = queue.popleft()
            out.append(i)
            queue.extend(self.children.get(i, []))
        return out


# --- parsing ----------------------------------------------------------------------------------
def _num(key: str, v: Any) -> float:
    if isinstance(v, bool):
        raise GridError(f"{key}: expected a number, got {v!r}")
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise GridError(f"{key}: expected a number, got {v!r}") from None
    if not math.isfinite(x):
        raise GridError(f"{key}: must be finite, got {v!r}")
    return x


def parse_axis(name: str, v: Any, *, max_len: int = 100000) -> Axis:
    """A number, a list of numbers, or {start, stop, step} (stop included when on the step)."""
    if isinstance(v, Mapping):
        extra = set(v) - {"start", "stop", "step"}
        missing = {"start", "stop", "step"} - set(v)
        if extra or missing:
            raise GridError(f"{name}: a range needs exactly the keys start, stop, step "
                            f"(missing {sorted(missing)}, unexpected {sorted(extra)})")
        a, b, h = (_num(f"{name}.{k}", v[k]) for k in ("start", "stop", "step"))
        if h <= 0:
            raise GridError(f"{name}: step must be > 0, got {h}")
        if b < a:
            raise GridError(f"{name}: stop {b} is below start {a}; swap them")
        n = int(math.floor((b - a) / h + 1e-9)) + 1
        if n > max_len:
            raise GridError(f"{name}: {n} values; at most {max_len} per axis (raise the step)")
        return Axis(name, [round(a + i * h, _DIGITS) for i in range(n)], h)
    if isinstance(v, (list, tuple)):
        if not v:
            raise GridError(f"{name}: empty list; give at least one value")
        vals = [round(_num(f"{name}[{i}]", x), _DIGITS) for i, x in enumerate(v)]
        if len(set(vals)) != len(vals):
            raise GridError(f"{name}: values repeat: {vals}")
        vals.sort()
        step = min(np.diff(vals)) if len(vals) > 1 else 0.0
        return Axis(name, vals, float(step))
    return Axis(name, [round(_num(name, v), _DIGITS)], 0.0)


def _joint_axes(name: str, v: Any, nj: int) -> list[Axis]:
    if nj == 1:
        return [parse_axis(name, v)]
    if not isinstance(v, (list, tuple)) or len(v) != nj:
        raise GridError(f"{name}: model with {nj} joints needs a list of {nj} axes (one per joint, "
                        f"each a number, a list or {{start, stop, step}}), got {v!r}")
    return [parse_axis(f"{name}[{j + 1}]", x) for j, x in enumerate(v)]


def parse_grid(data: Mapping[str, Any], base_dir: Optional[Path] = None) -> GridSpec:
    """Check and parse a grid mapping (see module docstring); raises GridError. Relative TLS file
    names are taken from ``base_dir`` (default: the working directory)."""
    if not isinstance(data, Mapping):
        raise GridError("a grid file must hold a mapping (model, q0, qf, tf, ...)")
    extra = sorted(set(data) - set(_KEYS))
    if extra:
        raise GridError(f"unknown key(s) {extra}; known keys: {', '.join(_KEYS)}")
    for k in ("q0", "qf", "tf"):
        if k not in data:
            raise GridError(f"missing key {k!r}: give a number, a list or {{start, stop, step}}")
    model = str(data.get("model", "arm1dof"))
    if model not in MODELS:
        raise GridError(f"model: unknown model {model!r}; known models: {', '.join(MODELS)}")
    try:
        base = preset(str(data["preset"])) if "preset" in data else default_params(model)
        if base.model != model:
            raise GridError(f"preset {data['preset']!r} is for model '{base.model}', not '{model}'")
        over = data.get("params") or {}
        if not isinstance(over, Mapping):
            raise GridError("params: expected a mapping of parameter overrides, e.g. {pc: 0.2}")
        params = base.replace(**{str(k): _num(f"params.{k}", v) for k, v in over.items()}) if over else base
    except ParameterError as exc:
        raise GridError(f"params: {exc}") from None
    objective = str(data.get("objective", "robust-derivative"))
    if objective not in OBJECTIVES:
        raise GridError(f"objective: unknown {objective!r}; use one of {', '.join(OBJECTIVES)}")
    unc = data.get("uncertain", list(params.default_uncertain))
    if isinstance(unc, str):
        unc = [u.strip() for u in unc.split(",") if u.strip()]
    uncertain = [str(u) for u in unc]
    bad = [u for u in uncertain if u not in params.friction_keys]
    if bad:
        raise GridError(f"uncertain: unknown parameter(s) {bad} for {model}; choose from "
                        f"{', '.join(params.friction_keys)}")
    steps = data.get("steps")
    steps = None if steps in (None, 0) else int(_num("steps", steps))
    nj = n_joints(model)
    zero = str(data.get("zero_moves", "skip"))
    if zero not in ("skip", "keep"):
        raise GridError(f"zero_moves: use skip or keep, got {zero!r}")
    spec = GridSpec(
        model=model, params=params, objective=objective, uncertain=uncertain, steps=steps,
        coast=_num("coast", data.get("coast", DEFAULT_COAST)),
        starts=int(_num("starts", data.get("starts", 50))), seed=int(_num("seed", data.get("seed", 0))),
        time_budget=_num("time_budget", data.get("time_budget", 60.0)),
        tol=_num("tol", data.get("tol", 1e-6)),
        q0=_joint_axes("q0", data["q0"], nj), qf=_joint_axes("qf", data["qf"], nj),
        tf=parse_axis("tf", data["tf"]), zero_moves=zero,
        max_tasks=int(_num("max_tasks", data.get("max_tasks", 100000))), name=str(data.get("name", "")))
    if data.get("switch_grid") not in (None, 0, 0.0):
        g = _num("switch_grid", data["switch_grid"])
        if not 0.0 < g < min(spec.tf.values):
            raise GridError(f"switch_grid: must be a positive time below the shortest move time, got {g}")
        if not applies(model, objective):
            raise GridError(f"switch_grid: the {model} {objective} planner does not place switch times on "
                            f"a grid; remove switch_grid")
        spec.switch_grid = g
    try:
        spec.scheduler = settings_from_mapping(data, base_dir)
        if spec.scheduler is not None:
            parse_address(spec.scheduler.address)
    except ClusterError as exc:
        raise GridError(str(exc)) from None
    if min(spec.tf.values) <= spec.coast:
        raise GridError(f"tf: every move time must exceed the coast of {spec.coast} s; "
                        f"smallest is {min(spec.tf.values)} s")
    if spec.size() > spec.max_tasks:
        raise GridError(f"the grid has {spec.size()} tasks, more than max_tasks = {spec.max_tasks}; "
                        f"coarsen the steps or raise max_tasks")
    return spec


def load_grid(source: Union[str, Path, Mapping[str, Any]]) -> GridSpec:
    """A GridSpec from a YAML file or a mapping; raises GridError naming what to change."""
    if isinstance(source, (str, Path)):

        p = Path(source)
        if not p.is_file():
            raise GridError(f"grid file {str(p)!r} not found")
        try:
            data = yaml.safe_load(p.read_text(encoding="utf-8"))
        except yaml.YAMLError as exc:
            raise GridError(f"{p}: not valid YAML: {exc}") from None
        return parse_grid(data or {}, p.parent)
    return parse_grid(source)


# --- expansion --------------------------------------------------------------------------------
def _request(spec: GridSpec, q0: Sequence[float], qf: Sequence[float], tf: float) -> PlanRequest:
    kw: dict[str, Any] = dict(model=spec.model, q0=[float(x) for x in q0], qf=[float(x) for x in qf],
                              tf=float(tf), uncertain=list(spec.uncertain), objective=spec.objective,
                              steps=spec.steps, starts=spec.starts, seed=spec.seed,
                              time_budget=spec.time_budget, coast=spec.coast, params=spec.params, tol=spec.tol)
    return GridPlanRequest(grid=spec.switch_grid, **kw) if spec.switch_grid else PlanRequest(**kw)


def expand(spec: GridSpec) -> Grid:
    """All tasks of the grid, with shift twins grouped and the continuation tree built."""
    nj = len(spec.q0)
    tasks: list[GridTask] = []
    skipped = 0
    for idx in itertools.product(*(range(len(a)) for a in spec.axes)):
        vals = [a.values[i] for a, i in zip(spec.axes, idx)]
        q0, qf, tf = vals[:nj], vals[nj:2 * nj], vals[-1]
        if spec.zero_moves == "skip" and all(abs(a - b) < 1e-12 for a, b in zip(q0, qf)):
            skipped += 1
            continue
        req = _request(spec, q0, qf, tf)
        try:
            req.validate()
        except (PlanningError, ParameterError) as exc:
            raise GridError(f"task q0={q0} qf={qf} tf={tf}: {exc}") from None
        tasks.append(GridTask(tuple(idx), req, task_key(req),
                              np.round(canonical_coords(spec.model, q0, qf, tf), _DIGITS)))
    if not tasks:
        raise GridError("the grid holds no task (every move has qf == q0?); widen q0/qf or set "
                        "zero_moves: keep")
    grid = Grid(spec, tasks, [], skipped_zero=skipped)
    first: dict[tuple, int] = {}
    for i, t in enumerate(tasks):
        c = tuple(float(x) for x in t.coords)
        if c in first:
            t.rep = first[c]
            grid.twins.setdefault(first[c], []).append(i)
        else:
            first[c] = i
            t.rep = i
            grid.reps.append(i)
    continuation_tree(grid)
    return grid


def _scales(spec: GridSpec) -> np.ndarray:
    """Grid-step units for the canonical coordinates (so one step in any direction counts 1)."""
    nj = len(spec.q0)
    qsteps = [a.step for a in [*spec.q0, *spec.qf] if a.step > 0]
    qs = min(qsteps) if qsteps else 1.0
    ts = spec.tf.step if spec.tf.step > 0 else 1.0
    return np.array([qs] * (2 * nj - 1) + [ts])


def continuation_tree(grid: Grid, n_roots: int = 1) -> None:
    """Set parent/depth of every representative: BFS over the grid-step MST, rooted at its centre.

    ``n_roots`` > 1 cuts each connected part into that many subtrees (more parallel cold starts).
    """

    reps = grid.reps
    n = len(reps)
    for i in reps:
        grid.tasks[i].parent, grid.tasks[i].depth = -1, 0
    grid.children, grid.roots = {}, []
    if n == 1:
        grid.roots = [reps[0]]
        return
    pts = np.array([grid.tasks[i].coords for i in reps]) / _scales(grid.spec)
    k = min(n, 2 * pts.shape[1] + 3)
    dist, nb = cKDTree(pts).query(pts, k=k)
    rows = np.repeat(np.arange(n), k)
    w = dist.ravel() + 1e-9 * (1 + np.abs(rows - nb.ravel()))   # ties broken by grid order
    g = coo_matrix((w, (rows, nb.ravel())), shape=(n, n)).tocsr()
    g = g.maximum(g.T)
    g.setdiag(0)
    g.eliminate_zeros()
    ncomp, _ = connected_components(g, directed=False)
    if ncomp > 1:   # k-NN graph split: join the parts through the full distance matrix (small grids)

        g = coo_matrix(cdist(pts, pts) + 1e-9).tocsr()
        g.setdiag(0)
        g.eliminate_zeros()
    mst = minimum_spanning_tree(g)
    mst = mst.maximum(mst.T).tolil()
    adj = [list(r) for r in mst.rows]

    def bfs(*srcs: int) -> tuple[list[int], list[int]]:
        """Multi-source BFS over the MST: parent (-1 at a source, -2 unreached) and depth."""
        par, dep = [-2] * n, [0] * n
        q: deque[int] = deque()
        for src in srcs:
            par[src] = -1
            q.append(src)
        while q:
            u = q.popleft()
            for v in sorted(adj[u]):
                if par[v] == -2:
                    par[v], dep[v] = u, dep[u] + 1
                    q.append(v)
        return par, dep

    seen = [False] * n
    roots: list[int] = []
    for s in range(n):
        if seen[s]:
            continue
        par, dep = bfs(s)
        comp = [i for i in range(n) if par[i] != -2]
        a = max(comp, key=lambda i: (dep[i], -i))
        par, dep = bfs(a)
        b = max(comp, key=lambda i: (dep[i], -i))
        path = [b]
        while par[path[-1]] != -1:
            path.append(par[path[-1]])
        comp_roots = [path[len(path) // 2]]          # the tree's centre
        if n_roots > 1 and len(comp) > n_roots:
            # more roots (cold starts): greedily the node farthest (in tree hops) from the chosen
            # roots' centre-of-subtree, i.e. the one a multi-source BFS reaches last
            for _ in range(n_roots - 1):
                _, d = bfs(*comp_roots)
                far = max(comp, key=lambda i: (d[i], -i))
                # place the new root halfway from its nearest root to the far node
                p_, _ = bfs(*comp_roots)
                chain = [far]
                while p_[chain[-1]] != -1:
                    chain.append(p_[chain[-1]])
                comp_roots.append(chain[len(chain) // 2])
        par, dep = bfs(*comp_roots)
        for i in comp:
            seen[i] = True
            t = grid.tasks[reps[i]]
            t.parent = reps[par[i]] if par[i] >= 0 else -1
            t.depth = dep[i]
            if par[i] >= 0:
                grid.children.setdefault(reps[par[i]], []).append(reps[i])
        roots.extend(reps[r] for r in comp_roots)
    for v in grid.children.values():
        v.sort()
    grid.roots = sorted(roots)


def describe(grid: Grid) -> dict[str, Any]:
    """Counts for logs and the CLI: tasks, distinct motions, roots, tree depth."""
    reps = grid.reps
    return {"tasks": len(grid.tasks), "distinct_motions": len(reps),
            "shift_copies": len(grid.tasks) - len(reps), "zero_moves_skipped": grid.skipped_zero,
            "roots": len(grid.roots),
            "tree_depth": max(grid.tasks[i].depth for i in reps) if reps else 0,
            "axes": {a.name: len(a) for a in grid.spec.axes}}

"""The motion library: solved (and unsolvable) plans on disk, for warm starts (paper section 6.4).

One SQLite file (WAL journal), safe for several writer processes (the planner node, the Dask
builder's workers). One row per task, keyed by ``task_key`` = a hash of

    model, hash of every model parameter, objective, uncertain set, steps, coast, q0, qf, tf

and written exactly once: the first writer of a key wins; a later ``put`` only replaces a row when
it is strictly better (a solved plan over an infeasible/failed one, a robust one over a
best-effort one) — see :meth:`MotionLibrary.put`.

Lookups never cross a parameter set: a row whose model parameters differ from the request's has
another ``params_hash`` and is invisible (invalidation by key); :meth:`MotionLibrary.purge_stale`
deletes such rows for good.

Nearest neighbours are found in *canonical task coordinates* (:func:`canonical_coords`): both arms
move in the horizontal plane, so their dynamics do not change when every joint angle is shifted by
the same amount (1-DOF: only qf − q0 matters; 2-DOF in absolute angles: only differences of angles
matter). A request that is a pure shift of a stored task (distance 0) can reuse that plan as is.

Units: rad, s, A. No ROS here.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import sqlite3
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from ff_planner.export.motion_file import motion_to_dict
from ff_planner.model.params import Params
from ff_planner.model.profile import CurrentProfile, PlanRequest, PlanResult

SCHEMA_VERSION = 1

#: Row statuses. "failed" is transient (time budget, internal error): a later solve may replace it.
STATUSES = ("solved", "infeasible", "failed")
#: How a stored plan was found.
SOLVED_HOW = ("cold", "warm", "continuation", "shift")

#: Error codes that mean "no plan exists here as asked" (stored as infeasible, not retried).
INFEASIBLE_CODES = ("UNREACHABLE", "NO_ROBUST_PLAN")

_DIGITS = 9  # task coordinates are rounded to 1e-9 (rad, s) in keys


class LibraryError(ValueError):
    """A library file or record that cannot be used; the message says what to change."""


# --- keys -------------------------------------------------------------------------------------
def _canon(x: float) -> float:
    v = round(float(x), _DIGITS)
    return 0.0 if v == 0.0 else v  # no "-0.0" in keys


def params_hash(params: Params) -> str:
    """Hash of the model id and every model parameter (SI units): equal iff the parameters are."""
    blob = json.dumps({"model": params.model,
                       "params": {k: repr(float(v)) for k, v in sorted(params.to_dict().items())}},
                      sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:24]


def uncertain_key(uncertain: Sequence[str]) -> str:
    """The uncertain *set* as stored: sorted, comma-separated (order does not change the task)."""
    return ",".join(sorted(str(u) for u in uncertain))


def task_key(request: PlanRequest) -> str:
    """The exactly-once key of a task (see module docstring)."""
    p = request.resolved_params()
    blob = json.dumps({"model": request.model, "params": params_hash(p),
                       "objective": request.objective, "uncertain": uncertain_key(request.uncertain),
                       "steps": request.n_steps(), "coast": _canon(request.coast),
                       "q0": [_canon(x) for x in request.q0], "qf": [_canon(x) for x in request.qf],
                       "tf": _canon(request.tf)}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:32]


def canonical_coords(model: str, q0: Sequence[float], qf: Sequence[float], tf: float) -> np.ndarray:
    """Task coordinates invariant under a common shift of all joint angles (rad, rad, s).

    arm1dof: (qf − q0, tf).  scara2: (q0₂ − q0₁, qf₁ − q0₁, qf₂ − q0₁, tf).
    """
    q0a = np.asarray(q0, dtype=float).ravel()
    qfa = np.asarray(qf, dtype=float).ravel()
    ref = q0a[0]
    return np.concatenate([q0a[1:] - ref, qfa - ref, [float(tf)]])


def _floats_or_nan(values: Optional[Sequence]) -> np.ndarray:
    """JSON numbers (None for a non-finite value) -> float array."""
    return np.array([math.nan if v is None else float(v) for v in (values or [])], dtype=float)


# --- records ----------------------------------------------------------------------------------
@dataclass
class MotionRecord:
    """One library row. ``motion`` is the ff-motion/1 dict (None when no plan was found)."""

    task_key: str
    model: str
    params_hash: str
    objective: str
    uncertain: list[str]
    steps: int
    coast: float                     # s
    q0: list[float]                  # rad
    qf: list[float]                  # rad
    tf: float                        # s
    status: str                      # "solved" | "infeasible" | "failed"
    reason: str = ""                 # why not solved (or notes)
    error_code: str = "OK"           # PlanTrajectory error name
    robust: bool = False
    max_abs_sensitivity: Optional[float] = None   # max |dq(tf)/dp| (true derivatives), rad per unit
    final_error: Optional[float] = None           # max |q(tf) − qf|, rad, nominal parameters
    final_speed: Optional[float] = None           # max |qd(tf)|, rad/s, nominal parameters
    motion: Optional[dict] = None
    solved_how: str = "cold"         # "cold" | "warm" | "continuation" | "shift"
    warm_from: Optional[str] = None  # task_key of the neighbour it started from
    starts_tried: int = 0
    iterations: int = 0
    solve_time: float = 0.0          # s
    created: float = field(default_factory=time.time)
    writer: str = ""

    def currents(self) -> Optional[np.ndarray]:
        """The stored currents (N, n_joints), A; None without a motion."""
        if not self.motion:
            return None
        return np.asarray(self.motion["currents"], dtype=float).reshape(len(self.motion["currents"]), -1)

    def profile(self) -> Optional[CurrentProfile]:
        """The stored plan as a CurrentProfile (s, A); None without a motion."""
        cur = self.currents()
        if cur is None or not self.motion:
            return None
        m = self.motion
        return CurrentProfile(np.asarray(m["step_times"], float), cur, float(m["tf"]), float(m["coast"]))

    def rank(self) -> int:
        """Quality order used by put(upgrade): failed < infeasible < solved best-effort < solved robust."""
        if self.status == "solved":
            return 3 if self.robust else 2
        return 1 if self.status == "infeasible" else 0

    def to_result(self, request: PlanRequest, *, message: str = "", shift: bool = False) -> PlanResult:
        """This record as the PlanResult of ``request`` (warm_start=True).

        ``shift``: the request is a shifted copy of this task (same canonical coordinates); the
        predicted final position is moved by the request's offset.
        """
        q0 = np.asarray(request.q0, float)
        qf = np.asarray(request.qf, float)
        prof = self.profile()
        pred = (self.motion or {}).get("predicted", {})
        q_final = _floats_or_nan(pred.get("q_final"))
        if shift and q_final.size:
            q_final = q_final + (q0[0] - self.q0[0])
        ok = self.status == "solved"
        return PlanResult(
            success=ok, message=message or self.reason, profile=prof, model=self.model,
            params=request.resolved_params(), q0=q0, qf=qf, uncertain=list(request.uncertain),
            objective=self.objective, q_final=q_final,
            qd_final=_floats_or_nan(pred.get("qd_final")),
            sensitivities={k: (math.nan if v is None else float(v))
                           for k, v in (pred.get("sensitivities") or {}).items()},
            robust=bool(self.robust), error_code="OK" if ok else (self.error_code or "NO_ROBUST_PLAN"),
            best_effort=ok and not self.robust and self.objective.startswith("robust"),
            starts_tried=0, iterations=0, solve_time=0.0, warm_start=True,
            extra={"library": "shift" if shift else "hit", "library_key": self.task_key})


def motion_dict(result: PlanResult, request: PlanRequest) -> Optional[dict]:
    """The ff-motion/1 dict of a result via ff_planner.export.motion_file (None without a profile)."""
    if result.profile is None:
        return None

    if result.params is None:
        result.params = request.resolved_params()
    return motion_to_dict(result)


def record_from_result(request: PlanRequest, result: PlanResult, *, solved_how: Optional[str] = None,
                       warm_from: Optional[str] = None, writer: str = "") -> MotionRecord:
    """A library row for ``result`` of ``request``: solved, infeasible (with reason) or failed."""
    if result.success:
        status = "solved"
    elif result.error_code in INFEASIBLE_CODES:
        status = "infeasible"
    else:
        status = "failed"
    sens = [abs(v) for v in result.sensitivities.values() if math.isfinite(v)]
    qf = np.asarray(result.qf if np.size(result.qf) else request.qf, float).ravel()
    qfin = np.asarray(result.q_final, float).ravel()
    qdfin = np.asarray(result.qd_final, float).ravel()
    how = solved_how or ("warm" if result.warm_start else "cold")
    if how not in SOLVED_HOW:
        raise LibraryError(f"solved_how must be one of {SOLVED_HOW}, got {how!r}")
    return MotionRecord(
        task_key=task_key(request), model=request.model,
        params_hash=params_hash(request.resolved_params()), objective=request.objective,
        uncertain=sorted(request.uncertain), steps=request.n_steps(), coast=float(request.coast),
        q0=[float(x) for x in request.q0], qf=[float(x) for x in request.qf], tf=float(request.tf),
        status=status, reason="" if result.success else str(result.message),
        error_code=str(result.error_code), robust=bool(result.robust),
        max_abs_sensitivity=max(sens) if sens else None,
        final_error=float(np.max(np.abs(qfin - qf))) if qfin.size == qf.size and qf.size else None,
        final_speed=float(np.max(np.abs(qdfin))) if qdfin.size else None,
        motion=motion_dict(result, request), solved_how=how, warm_from=warm_from,
        starts_tried=int(result.starts_tried), iterations=int(result.iterations),
        solve_time=float(result.solve_time), writer=writer)


# --- the store --------------------------------------------------------------------------------
_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS param_sets (
    params_hash TEXT PRIMARY KEY, model TEXT NOT NULL, params TEXT NOT NULL, created REAL NOT NULL);
CREATE TABLE IF NOT EXISTS motions (
    task_key TEXT PRIMARY KEY,
    model TEXT NOT NULL, params_hash TEXT NOT NULL, objective TEXT NOT NULL,
    uncertain TEXT NOT NULL, steps INTEGER NOT NULL, coast REAL NOT NULL,
    q0 TEXT NOT NULL, qf TEXT NOT NULL, tf REAL NOT NULL, coords TEXT NOT NULL,
    c0 REAL NOT NULL DEFAULT 0, c1 REAL NOT NULL DEFAULT 0, c2 REAL NOT NULL DEFAULT 0,
    c3 REAL NOT NULL DEFAULT 0,
    status TEXT NOT NULL CHECK (status IN ('solved', 'infeasible', 'failed')),
    reason TEXT NOT NULL DEFAULT '', error_code TEXT NOT NULL DEFAULT 'OK',
    robust INTEGER NOT NULL DEFAULT 0, rank INTEGER NOT NULL DEFAULT 0,
    max_abs_sensitivity REAL, final_error REAL, final_speed REAL,
    motion TEXT, solved_how TEXT NOT NULL DEFAULT 'cold', warm_from TEXT,
    starts_tried INTEGER NOT NULL DEFAULT 0, iterations INTEGER NOT NULL DEFAULT 0,
    solve_time REAL NOT NULL DEFAULT 0, created REAL NOT NULL, writer TEXT NOT NULL DEFAULT '');
CREATE INDEX IF NOT EXISTS motions_near
    ON motions (model, params_hash, objective, uncertain, steps, coast, status, c0);
"""

_COLUMNS = ("task_key", "model", "params_hash", "objective", "uncertain", "steps", "coast", "q0", "qf",
            "tf", "coords", "status", "reason", "error_code", "robust", "rank", "max_abs_sensitivity",
            "final_error", "final_speed", "motion", "solved_how", "warm_from", "starts_tried",
            "iterations", "solve_time", "created", "writer", "c0", "c1", "c2", "c3")
_N_COORDS = 4   # canonical coordinates kept as REAL columns c0..c3 (scara2 has 4, arm1dof 2)


def _padded(coords: np.ndarray) -> list[float]:
    c = [float(x) for x in coords]
    if len(c) > _N_COORDS:
        raise LibraryError(f"{len(c)} task coordinates, the store keeps {_N_COORDS}")
    return c + [0.0] * (_N_COORDS - len(c))


class MotionLibrary:
    """A motion library file. Thread-safe (one connection per thread); process-safe (WAL + locks)."""

    def __init__(self, path: str | os.PathLike, *, timeout: float = 30.0) -> None:
        self.path = Path(path).expanduser()
        if str(path) == "":
            raise LibraryError("motion library path is empty; give a file path such as ~/.ff/motions.sqlite")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.timeout = float(timeout)
        self._local = threading.local()
        self._all: list[sqlite3.Connection] = []
        self._lock = threading.Lock()
        self._init_schema(self._con())

    # connections
    def _con(self) -> sqlite3.Connection:
        con = getattr(self._local, "con", None)
        if con is None:
            con = sqlite3.connect(str(self.path), timeout=self.timeout, isolation_level=None,
                                  check_same_thread=False)
            con.execute(f"PRAGMA busy_timeout = {int(self.timeout * 1000)}")
            mode = con.execute("PRAGMA journal_mode = WAL").fetchone()[0]
            if str(mode).lower() != "wal":
                raise LibraryError(f"could not put {self.path} in WAL mode (got {mode}); "
                                   "use a local file system for the motion library")
            con.execute("PRAGMA synchronous = NORMAL")
            self._local.con = con
            with self._lock:
                self._all.append(con)
        return con

    class _write:
        """BEGIN IMMEDIATE ... COMMIT (ROLLBACK on error): one writer at a time across processes."""

        def __init__(self, con: sqlite3.Connection) -> None:
            self.con = con

        def __enter__(self) -> sqlite3.Connection:
            self.con.execute("BEGIN IMMEDIATE")
            return self.con

        def __exit__(self, exc_type, exc, tb) -> None:
            self.con.execute("COMMIT" if exc_type is None else "ROLLBACK")

    def _init_schema(self, con: sqlite3.Connection) -> None:
        with self._write(con):
            for stmt in filter(str.strip, _SCHEMA.split(";")):
                con.execute(stmt)
            row = con.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
            if row is None:
                con.execute("INSERT INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))
            elif int(row[0]) != SCHEMA_VERSION:
                raise LibraryError(f"{self.path} has schema version {row[0]}, this code reads "
                                   f"{SCHEMA_VERSION}; use another file or migrate it")

    def close(self) -> None:
        with self._lock:
            for con in self._all:
                try:
                    con.close()
                except sqlite3.Error:
                    pass
            self._all.clear()
        self._local = threading.local()

    def __enter__(self) -> "MotionLibrary":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # writing
    def put(self, record: MotionRecord, params: Optional[Params] = None, *, upgrade: bool = True) -> bool:
        """Store ``record`` under its task key; True if this call wrote it.

        Exactly once: if the key exists, nothing changes — unless ``upgrade`` and the new record
        ranks strictly higher (failed < infeasible < best-effort < robust solved), in which case
        it replaces the old one atomically. ``params`` (the model parameters) is stored once per
        parameter set for ``show``-style tools.
        """
        if record.status not in STATUSES:
            raise LibraryError(f"status must be one of {STATUSES}, got {record.status!r}")
        if record.status == "solved" and not record.motion:
            raise LibraryError("a solved record needs its motion (ff-motion/1 dict)")
        row = self._row(record)
        con = self._con()
        with self._write(con):
            if params is not None:
                con.execute("INSERT OR IGNORE INTO param_sets VALUES (?, ?, ?, ?)",
                            (params_hash(params), params.model, json.dumps(params.to_dict()), time.time()))
            cur = con.execute(f"INSERT OR IGNORE INTO motions ({', '.join(_COLUMNS)}) VALUES "
                              f"({', '.join('?' * len(_COLUMNS))})", row)
            if cur.rowcount == 1:
                return True
            if not upgrade:
                return False
            cur = con.execute(f"UPDATE motions SET ({', '.join(_COLUMNS[1:])}) = "
                              f"({', '.join('?' * (len(_COLUMNS) - 1))}) WHERE task_key = ? AND rank < ?",
                              (*row[1:], record.task_key, record.rank()))
            return cur.rowcount == 1

    def _row(self, r: MotionRecord) -> tuple:
        coords = canonical_coords(r.model, r.q0, r.qf, r.tf)
        return (r.task_key, r.model, r.params_hash, r.objective, uncertain_key(r.uncertain), int(r.steps),
                _canon(r.coast), json.dumps(r.q0), json.dumps(r.qf), float(r.tf),
                json.dumps([float(c) for c in coords]), r.status, r.reason, r.error_code, int(r.robust),
                r.rank(), r.max_abs_sensitivity, r.final_error, r.final_speed,
                json.dumps(r.motion) if r.motion is not None else None, r.solved_how, r.warm_from,
                int(r.starts_tried), int(r.iterations), float(r.solve_time), float(r.created), r.writer,
                *_padded(coords))

    @staticmethod
    def _record(row: sqlite3.Row | tuple) -> MotionRecord:
        d = dict(zip(_COLUMNS, row))
        return MotionRecord(
            task_key=d["task_key"], model=d["model"], params_hash=d["params_hash"],
            objective=d["objective"], uncertain=[u for u in d["uncertain"].split(",") if u],
            steps=int(d["steps"]), coast=float(d["coast"]), q0=json.loads(d["q0"]),
            qf=json.loads(d["qf"]), tf=float(d["tf"]), status=d["status"], reason=d["reason"],
            error_code=d["error_code"], robust=bool(d["robust"]),
            max_abs_sensitivity=d["max_abs_sensitivity"], final_error=d["final_error"],
            final_speed=d["final_speed"], motion=json.loads(d["motion"]) if d["motion"] else None,
            solved_how=d["solved_how"], warm_from=d["warm_from"], starts_tried=int(d["starts_tried"]),
            iterations=int(d["iterations"]), solve_time=float(d["solve_time"]),
            created=float(d["created"]), writer=d["writer"])

    # reading
    def get(self, key: str) -> Optional[MotionRecord]:
        """The row with task key ``key``, or None."""
        row = self._con().execute(f"SELECT {', '.join(_COLUMNS)} FROM motions WHERE task_key = ?",
                                  (key,)).fetchone()
        return self._record(row) if row else None

    def lookup(self, request: PlanRequest) -> Optional[MotionRecord]:
        """The row of exactly this task (same parameters), or None."""
        return self.get(task_key(request))

    def __contains__(self, key: str) -> bool:
        return self._con().execute("SELECT 1 FROM motions WHERE task_key = ?", (key,)).fetchone() is not None

    def nearest(self, request: PlanRequest, *, k: int = 1, max_distance: float = math.inf,
                statuses: Sequence[str] = ("solved",), time_weight: float = 1.0
                ) -> list[tuple[float, MotionRecord]]:
        """Up to ``k`` rows of the same model, parameters, objective, uncertain set, steps and coast,
        nearest in canonical coordinates; distance = Euclidean, tf weighted by ``time_weight`` rad/s.
        """
        p = request.resolved_params()
        here = _padded(canonical_coords(request.model, request.q0, request.qf, request.tf))
        w = [1.0] * _N_COORDS
        w[len(request.q0) * 2 - 1] = float(time_weight)   # the tf coordinate
        dist2 = " + ".join(f"(c{i} - ?) * (c{i} - ?) * {w[i] * w[i]!r}" for i in range(_N_COORDS))
        marks = ", ".join("?" * len(statuses))
        args: list = []
        for x in here:
            args += [x, x]
        rows = self._con().execute(
            f"SELECT task_key, {dist2} AS d2 FROM motions WHERE model = ? AND params_hash = ? "
            f"AND objective = ? AND uncertain = ? AND steps = ? AND coast = ? AND status IN ({marks}) "
            f"AND c0 BETWEEN ? AND ? ORDER BY d2, task_key LIMIT ?",
            (*args, request.model, params_hash(p), request.objective, uncertain_key(request.uncertain),
             request.n_steps(), _canon(request.coast), *statuses, here[0] - max_distance / w[0],
             here[0] + max_distance / w[0], max(1, int(k)))).fetchall()
        out = []
        for key, d2 in rows:
            d = math.sqrt(max(0.0, d2))
            if d > max_distance:
                break
            rec = self.get(key)
            if rec is not None:
                out.append((d, rec))
        return out

    def records(self, *, model: Optional[str] = None, params: Optional[Params] = None,
                status: Optional[str] = None) -> list[MotionRecord]:
        """All rows, optionally filtered (for summaries and tests)."""
        where, args = [], []
        if model:
            where.append("model = ?")
            args.append(model)
        if params is not None:
            where.append("params_hash = ?")
            args.append(params_hash(params))
        if status:
            where.append("status = ?")
            args.append(status)
        sql = f"SELECT {', '.join(_COLUMNS)} FROM motions"
        if where:
            sql += " WHERE " + " AND ".join(where)
        return [self._record(r) for r in self._con().execute(sql + " ORDER BY created", args)]

    def count(self, status: Optional[str] = None) -> int:
        if status:
            return int(self._con().execute("SELECT COUNT(*) FROM motions WHERE status = ?",
                                           (status,)).fetchone()[0])
        return int(self._con().execute("SELECT COUNT(*) FROM motions").fetchone()[0])

    def param_sets(self) -> dict[str, tuple[str, dict]]:
        """params_hash -> (model, parameter dict) of every parameter set stored."""
        return {h: (m, json.loads(p)) for h, m, p, _ in
                self._con().execute("SELECT params_hash, model, params, created FROM param_sets")}

    def purge_stale(self, current: Sequence[Params]) -> int:
        """Delete every row whose parameter set is not in ``current`` (per model); returns the count.

        Models not named in ``current`` are left alone.
        """
        keep: dict[str, set[str]] = {}
        for p in current:
            keep.setdefault(p.model, set()).add(params_hash(p))
        con = self._con()
        n = 0
        with self._write(con):
            for model, hashes in keep.items():
                marks = ", ".join("?" * len(hashes))
                n += con.execute(f"DELETE FROM motions WHERE model = ? AND params_hash NOT IN ({marks})",
                                 (model, *hashes)).rowcount
        return n

    def stats(self) -> dict[str, int]:
        """Row counts by status, and the number of parameter sets."""
        con = self._con()
        out = {s: 0 for s in STATUSES}
        for s, n in con.execute("SELECT status, COUNT(*) FROM motions GROUP BY status"):
            out[s] = int(n)
        out["param_sets"] = int(con.execute("SELECT COUNT(DISTINCT params_hash) FROM motions").fetchone()[0])
        return out

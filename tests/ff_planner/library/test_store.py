"""Motion library (ff_planner.library.store): keys, exactly-once writes from several processes,
invalidation by parameters, nearest neighbours, upgrade rules."""
from __future__ import annotations

import multiprocessing
import sqlite3

import numpy as np
import pytest

from ff_planner.library.store import (LibraryError, MotionLibrary, canonical_coords, params_hash,
                                      record_from_result, task_key)
from ff_planner.model.params import default_params
from ff_planner.model.profile import CurrentProfile, PlanRequest, PlanResult


def _request(q0=0.0, qf=1.0, tf=1.0, **kw) -> PlanRequest:
    return PlanRequest(model="arm1dof", q0=[q0], qf=[qf], tf=tf, uncertain=["pv", "pc", "pt"], **kw)


def _result(req: PlanRequest, success=True, robust=True, code="OK", currents=None, starts=10) -> PlanResult:
    cur = np.asarray(currents if currents is not None else [[1.0], [2.0], [-1.0], [0.5], [-2.5]])
    prof = CurrentProfile.uniform(cur, req.tf)
    return PlanResult(success=success, message="" if success else "no robust plan", profile=prof,
                      model=req.model, params=req.resolved_params(), q0=np.asarray(req.q0, float),
                      qf=np.asarray(req.qf, float), uncertain=list(req.uncertain), objective=req.objective,
                      q_final=np.asarray(req.qf, float), qd_final=np.zeros(1),
                      sensitivities={"pv": 1e-9, "pc": -2e-9, "pt": 0.0}, robust=robust, error_code=code,
                      starts_tried=starts)


@pytest.fixture
def lib(tmp_path):
    with MotionLibrary(tmp_path / "lib.sqlite") as m:
        yield m


def test_put_is_exactly_once_and_round_trips(lib):
    req = _request()
    rec = record_from_result(req, _result(req))
    assert lib.put(rec, req.resolved_params()) is True
    assert lib.put(rec) is False                   # same key again: nothing written
    got = lib.lookup(req)
    assert got is not None and got.status == "solved" and got.robust
    assert got.motion["format"] == "ff-motion/1"
    np.testing.assert_array_equal(got.currents(), _result(req).profile.currents)
    assert got.max_abs_sensitivity == pytest.approx(2e-9)
    assert lib.count() == 1
    res = got.to_result(req)
    assert res.success and res.warm_start and res.sensitivities["pc"] == pytest.approx(-2e-9)


def test_task_key_identity():
    a = _request()
    assert task_key(a) == task_key(_request())
    assert task_key(a) == task_key(PlanRequest(model="arm1dof", q0=[0.0], qf=[1.0], tf=1.0,
                                               uncertain=["pt", "pc", "pv"]))  # a set: order free
    assert task_key(a) != task_key(_request(qf=1.001))
    assert task_key(a) != task_key(_request(objective="robust-sampled"))
    assert task_key(a) != task_key(_request(steps=6))
    other = default_params("arm1dof").replace(pc=0.2)
    assert task_key(a) != task_key(_request(params=other))
    assert params_hash(other) != params_hash(default_params("arm1dof"))


def test_parameters_that_differ_are_never_used(lib):
    req = _request()
    lib.put(record_from_result(req, _result(req)), req.resolved_params())
    changed = _request(params=default_params("arm1dof").replace(pc=0.19 * 1.01))
    assert lib.lookup(changed) is None
    assert lib.nearest(changed) == []
    assert len(lib.nearest(_request(qf=1.1))) == 1
    assert lib.purge_stale([changed.resolved_params()]) == 1
    assert lib.count() == 0


def test_nearest_uses_shift_invariant_coordinates(lib):
    for qf in (1.0, 1.5, 2.0):
        r = _request(qf=qf)
        lib.put(record_from_result(r, _result(r)))
    hits = lib.nearest(_request(q0=3.0, qf=4.4), k=3)
    assert [round(d, 9) for d, _ in hits] == [0.1, 0.4, 0.6]
    assert hits[0][1].qf == [1.5]
    assert lib.nearest(_request(q0=3.0, qf=4.4), max_distance=0.05) == []
    shifted = lib.nearest(_request(q0=-2.0, qf=-1.0))
    assert shifted[0][0] == pytest.approx(0.0, abs=1e-12)
    res = shifted[0][1].to_result(_request(q0=-2.0, qf=-1.0), shift=True)
    assert res.q_final[0] == pytest.approx(-1.0)
    np.testing.assert_allclose(canonical_coords("scara2", [0.1, 0.3], [0.6, 0.2], 1.0),
                               canonical_coords("scara2", [1.1, 1.3], [1.6, 1.2], 1.0))


def test_upgrade_only_to_better(lib):
    req = _request()
    bad = record_from_result(req, _result(req, success=False, robust=False, code="NO_ROBUST_PLAN"))
    assert bad.status == "infeasible" and bad.reason
    assert lib.put(bad) is True
    good = record_from_result(req, _result(req))
    assert lib.put(good, upgrade=False) is False
    assert lib.lookup(req).status == "infeasible"
    assert lib.put(good) is True
    assert lib.lookup(req).status == "solved"
    assert lib.put(bad) is False                 # never downgraded
    assert lib.lookup(req).status == "solved" and lib.count() == 1


def _writer(path: str, worker: int, keys: int) -> list[bool]:
    out = []
    with MotionLibrary(path) as m:
        for i in range(keys):
            req = _request(qf=0.5 + 0.01 * i)
            out.append(m.put(record_from_result(req, _result(req), writer=f"w{worker}")))
            own = _request(qf=-0.5 - 0.01 * i - worker)
            assert m.put(record_from_result(own, _result(own), writer=f"w{worker}"))
    return out


@pytest.mark.integration
def test_concurrent_writers_in_processes_store_each_task_once(tmp_path):
    path = str(tmp_path / "shared.sqlite")
    MotionLibrary(path).close()
    keys, workers = 25, 4
    ctx = multiprocessing.get_context("spawn")
    with ctx.Pool(workers) as pool:
        wins = pool.starmap(_writer, [(path, w, keys) for w in range(workers)])
    won = np.array(wins)                      # (workers, keys): who inserted each shared key
    assert (won.sum(axis=0) == 1).all(), "every shared key inserted by exactly one writer"
    with MotionLibrary(path) as m:
        assert m.count() == keys + workers * keys
        con = sqlite3.connect(path)
        dup = con.execute("SELECT COUNT(*) FROM (SELECT task_key FROM motions GROUP BY task_key "
                          "HAVING COUNT(*) > 1)").fetchone()[0]
        assert dup == 0
        assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        con.close()


def test_schema_version_mismatch_is_refused(tmp_path):
    path = tmp_path / "old.sqlite"
    MotionLibrary(path).close()
    con = sqlite3.connect(path)
    con.execute("UPDATE meta SET value = '99' WHERE key = 'schema_version'")
    con.commit()
    con.close()
    with pytest.raises(LibraryError, match="schema version 99"):
        MotionLibrary(path)
    with pytest.raises(LibraryError, match="empty"):
        MotionLibrary("")


def test_failed_results_are_stored_as_failed_with_reason(lib):
    req = _request()
    res = _result(req, success=False, robust=False, code="TIME_BUDGET_EXHAUSTED")
    res.profile = None
    rec = record_from_result(req, res)
    assert rec.status == "failed" and rec.motion is None and rec.reason
    assert lib.put(rec) and lib.stats()["failed"] == 1
    assert lib.nearest(req) == []               # only solved rows are neighbours

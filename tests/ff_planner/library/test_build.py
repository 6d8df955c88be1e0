"""ff-library: grid files, continuation order, exactly-once builds (serial, and on a Dask
LocalCluster with a worker killed mid-run), failed/infeasible rows, the CLI."""
from __future__ import annotations

import json
import os
import signal
import sqlite3
import threading
import time

import numpy as np
import psutil  # a dependency of dask.distributed
import pytest
import yaml

from ff_planner.cli.library import main as cli_main
from ff_planner.library.build import build_library, start_local_cluster
from ff_planner.library.grid import GridError, continuation_tree, expand, load_grid, parse_grid
from ff_planner.library.store import MotionLibrary
from tests.support.stand_in_planners import broken_plan, delayed_plan

# 1-DOF, Coulomb uncertainty (k = 1, N = 3): robust plans exist almost everywhere and are fast.
GRID = {
    "model": "arm1dof", "preset": "table2", "objective": "robust-derivative", "uncertain": ["pc"],
    "starts": 200, "seed": 3, "time_budget": 60,
    "q0": [0.0, 0.25], "qf": {"start": 0.5, "stop": 1.25, "step": 0.25}, "tf": [0.9, 1.0],
}

def _content(lib: MotionLibrary) -> dict[str, tuple]:
    """What must not depend on workers or timing: status, how, neighbour, code, currents."""
    out = {}
    for r in lib.records():
        cur = r.currents()
        out[r.task_key] = (r.status, r.solved_how, r.warm_from, r.error_code, r.robust,
                           None if cur is None else cur.tobytes(), tuple(r.q0), tuple(r.qf), r.tf)
    return out


# --- grid files -----------------------------------------------------------------------------------
def test_grid_axes_ranges_and_twins():
    spec = parse_grid(GRID)
    assert spec.qf[0].values == [0.5, 0.75, 1.0, 1.25]          # stop included
    grid = expand(spec)
    assert len(grid.tasks) == 2 * 4 * 2                           # no qf == q0 here
    # the same motion shifted in angle is solved once: (0 -> 0.5) and (0.25 -> 0.75) ...
    assert len(grid.reps) == 10
    for rep, twins in grid.twins.items():
        for j in twins:
            np.testing.assert_allclose(grid.tasks[j].coords, grid.tasks[rep].coords)
    order = grid.order()
    assert sorted(order) == sorted(grid.reps) and len(grid.roots) == 1
    pos = {i: k for k, i in enumerate(order)}
    for i in grid.reps:
        p = grid.tasks[i].parent
        if p >= 0:   # parents come first and sit one grid step away
            assert pos[p] < pos[i]
            d = np.abs(grid.tasks[i].coords - grid.tasks[p].coords)
            assert np.count_nonzero(d > 1e-9) == 1 and (np.isclose(d.max(), 0.25) or np.isclose(d.max(), 0.1))


def test_more_roots_still_cover_every_motion_once():
    grid = expand(parse_grid({**GRID, "qf": {"start": 0.5, "stop": 1.5, "step": 0.1}, "tf": [0.9, 1.0, 1.1]}))
    depth1 = max(grid.tasks[i].depth for i in grid.reps)
    continuation_tree(grid, n_roots=3)
    order = grid.order()
    assert len(grid.roots) == 3 and sorted(order) == sorted(grid.reps)
    pos = {i: k for k, i in enumerate(order)}
    assert all(pos[grid.tasks[i].parent] < pos[i] for i in grid.reps if grid.tasks[i].parent >= 0)
    assert max(grid.tasks[i].depth for i in grid.reps) < depth1


def test_grid_scara2_and_errors(tmp_path):
    spec = parse_grid({"model": "scara2", "q0": [-0.5, 0.0], "qf": [{"start": 0.3, "stop": 0.5, "step": 0.1}, 0.0],
                       "tf": 1.0, "steps": 8})
    assert [len(a) for a in spec.axes] == [1, 1, 3, 1, 1]
    assert len(expand(spec).tasks) == 3
    bad = [({**GRID, "colour": 1}, "unknown key"),
           ({**GRID, "qf": {"start": 1, "stop": 0, "step": 0.1}}, "below start"),
           ({**GRID, "qf": {"start": 0, "stop": 1, "step": 0}}, "step must be > 0"),
           ({**GRID, "tf": 0.01}, "must exceed the coast"),
           ({**GRID, "uncertain": ["mu"]}, "unknown parameter"),
           ({**GRID, "params": {"zz": 1}}, "params"),
           ({**GRID, "max_tasks": 3}, "max_tasks"),
           ({"model": "scara2", "q0": 0.0, "qf": 1.0, "tf": 1.0}, "one per joint"),
           ({**GRID, "model": "delta"}, "unknown model")]
    for data, text in bad:
        with pytest.raises(GridError, match=text):
            parse_grid(data)
    f = tmp_path / "g.yaml"
    f.write_text("model: arm1dof\nq0: [0, \n")
    with pytest.raises(GridError, match="not valid YAML"):
        load_grid(f)


# --- builds ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def serial_library(tmp_path_factory):
    path = tmp_path_factory.mktemp("serial") / "lib.sqlite"
    rep = build_library(expand(parse_grid(GRID)), path, serial=True, progress=False)
    return path, rep


def test_serial_build_continues_from_neighbours_and_resumes(serial_library):
    path, rep = serial_library
    grid = expand(parse_grid(GRID))
    assert rep.failed == 0 and rep.solved + rep.infeasible == len(grid.tasks)
    with MotionLibrary(path) as lib:
        recs = {r.task_key: r for r in lib.records()}
        assert set(recs) == {t.key for t in grid.tasks}
        root = grid.tasks[grid.roots[0]]
        assert recs[root.key].solved_how == "cold" and recs[root.key].warm_from is None
        cont = [r for r in recs.values() if r.solved_how == "continuation"]
        assert cont, "no task was solved by continuation"
        for r in cont:   # the neighbour is the tree parent (or a solved ancestor), and it is stored
            assert r.warm_from in recs and recs[r.warm_from].status == "solved"
            assert 1 <= r.starts_tried <= 16     # local starts around the neighbour's plan
        for rep_i, twins in grid.twins.items():
            for j in twins:
                r = recs[grid.tasks[j].key]
                assert r.solved_how == "shift" and r.warm_from == grid.tasks[rep_i].key
                np.testing.assert_array_equal(r.currents(), recs[grid.tasks[rep_i].key].currents())
        before = _content(lib)
    again = build_library(grid, path, serial=True, progress=False)
    assert again.stored_before == len(grid.tasks) and again.distinct_solved == 0
    with MotionLibrary(path) as lib:
        assert _content(lib) == before


def test_an_interrupted_build_resumes_to_the_same_library(tmp_path, serial_library):
    serial_path, _ = serial_library
    grid = expand(parse_grid(GRID))
    path = tmp_path / "lib.sqlite"

    stored = []

    def stop(i, rec):
        stored.append(i)
        if len(stored) == 4:
            raise KeyboardInterrupt   # the client dies after storing 4 distinct motions
    with pytest.raises(KeyboardInterrupt):
        build_library(grid, path, serial=True, progress=False, on_result=stop)
    rep = build_library(grid, path, serial=True, progress=False)
    assert rep.stored_before >= 4 and rep.distinct_solved == len(grid.reps) - 4
    with MotionLibrary(path) as a, MotionLibrary(serial_path) as b:
        assert _content(a) == _content(b)


@pytest.mark.integration
def test_dask_build_with_a_worker_killed_mid_run_matches_serial(tmp_path, serial_library, capsys):
    """2 worker processes on 127.0.0.1; SIGKILL one while it plans; every task stored exactly once
    and identical to the serial build."""
    serial_path, _ = serial_library
    grid = expand(parse_grid(GRID))
    path = tmp_path / "dask.sqlite"
    cluster, client = start_local_cluster(2)
    killed: dict = {}
    lock = threading.Lock()

    def on_result(i, rec):
        with lock:
            if killed or on_result.n < 2:
                on_result.n += 1
                return
            pids = client.run(os.getpid)
            busy = []
            for _ in range(500):   # a worker that is planning right now
                busy = [w for w, keys in client.processing().items() if keys and w in pids]
                if busy:
                    break
                time.sleep(0.01)
            w = busy[0] if busy else sorted(pids)[0]
            killed.update(worker=w, pid=pids[w], running=list(client.processing()[w]))
            os.kill(pids[w], signal.SIGKILL)
    on_result.n = 0
    try:
        assert all(a.startswith("tcp://127.0.0.1:") for a in client.scheduler_info()["workers"])
        assert client.scheduler.address.startswith("tcp://127.0.0.1:")
        # every port this cluster listens on (scheduler + its HTTP API here, nannies, workers) is loopback
        ours = {os.getpid(), *client.run(os.getpid).values(), *client.run(os.getppid).values()}
        listening = [c.laddr for p in ours for c in psutil.Process(p).net_connections(kind="inet")
                     if c.status == psutil.CONN_LISTEN]
        assert len(listening) >= 5 and all(a.ip == "127.0.0.1" for a in listening), listening
        rep = build_library(grid, path, client=client, progress=False,
                            plan_fn=delayed_plan, on_result=on_result)
        # the same grid again through the CLI on this (existing) scheduler: everything is skipped
        gfile = tmp_path / "grid.yaml"
        gfile.write_text(json.dumps(GRID))
        capsys.readouterr()
        assert cli_main(["build", str(gfile), "--library", str(path), "--scheduler",
                         client.scheduler.address, "--json"]) == 0
        again = json.loads(capsys.readouterr().out)
        assert again["stored_before"] == len(grid.tasks) and again["distinct_solved"] == 0
        assert again["scheduler"] == client.scheduler.address
    finally:
        client.close()
        cluster.close()
    assert killed, "no worker was killed"
    assert rep.failed == 0 and not rep.worker_errors
    assert rep.solved + rep.infeasible == len(grid.tasks)
    with sqlite3.connect(path) as con:
        keys = [k for (k,) in con.execute("SELECT task_key FROM motions")]
    assert sorted(keys) == sorted(t.key for t in grid.tasks)          # each task once, none extra
    with MotionLibrary(path) as a, MotionLibrary(serial_path) as b:
        assert _content(a) == _content(b)
        # the task that was running on the killed worker was retried and stored
        for k in killed["running"]:
            assert a.get(k.removeprefix("ff-library-")).status in ("solved", "infeasible")


def test_failed_and_infeasible_rows_keep_their_reason_and_failed_ones_are_retried(tmp_path):
    data = {**GRID, "q0": 0.0, "qf": [0.5, 8.0], "tf": 0.5}     # 8 rad in 0.5 s is out of reach (reach ~5.1 rad)
    grid = expand(parse_grid(data))
    path = tmp_path / "lib.sqlite"
    rep = build_library(grid, path, serial=True, progress=False, plan_fn=broken_plan)
    assert rep.failed == 2
    with MotionLibrary(path) as lib:
        rows = lib.records()
        assert {r.status for r in rows} == {"failed"}
        assert all("planner exploded" in r.reason for r in rows)
    rep = build_library(grid, path, serial=True, progress=False)
    assert rep.failed == 0 and rep.stored_before == 0 and rep.infeasible == 1
    with MotionLibrary(path) as lib:
        far = lib.lookup(grid.tasks[1].request)
        assert far.status == "infeasible" and far.error_code == "UNREACHABLE" and "unreachable" in far.reason
        assert lib.lookup(grid.tasks[0].request).status == "solved"
        assert lib.count() == 2


# --- CLI ------------------------------------------------------------------------------------------
def test_cli_show_and_errors(tmp_path, serial_library, capsys):
    path, _ = serial_library
    png = tmp_path / "map.png"
    assert cli_main(["show", "--library", str(path), "--png", str(png), "--limit", "3"]) == 0
    out = capsys.readouterr().out
    assert "robust-derivative" in out and "continuation" in out and "more (--limit)" in out
    assert png.stat().st_size > 10000 and png.read_bytes()[:4] == b"\x89PNG"
    assert cli_main(["show", "--library", str(tmp_path / "none.sqlite")]) == 2
    assert "no motion library" in capsys.readouterr().err
    small = tmp_path / "small.yaml"
    small.write_text(json.dumps({**GRID, "q0": 0.0, "qf": [0.5, 0.75], "tf": 1.0}))
    assert cli_main(["build", str(small), "--library", str(tmp_path / "s.sqlite"), "--serial"]) == 0
    cap = capsys.readouterr()
    assert "2 solved" in cap.out
    assert "2/2 done" in cap.err and "0 remaining" in cap.err and "ETA" in cap.err   # progress bar
    bad = tmp_path / "bad.yaml"
    bad.write_text("model: arm1dof\nq0: 0\nqf: {start: 0, stop: 1}\ntf: 1\n")
    assert cli_main(["build", str(bad), "--library", str(tmp_path / "x.sqlite"), "--serial"]) == 2
    assert "start, stop, step" in capsys.readouterr().err


def test_a_scheduler_without_workers_is_given_up_on_with_one_line(tmp_path, capsys):
    """A cluster with no worker: the build stops after --worker-wait, says so in one line and
    writes no library (without the wait its tasks would queue forever)."""
    from distributed import LocalCluster

    grid = tmp_path / "grid.yaml"
    grid.write_text(yaml.safe_dump({**GRID, "qf": [0.5], "q0": [0.0], "tf": [1.0]}))
    lib = tmp_path / "lib.sqlite"
    with LocalCluster(n_workers=0, processes=False, protocol="tcp://", host="127.0.0.1", scheduler_port=0,
                      dashboard_address=None) as cluster:
        capsys.readouterr()
        t0 = time.monotonic()
        rc = cli_main(["build", str(grid), "--library", str(lib), "--scheduler", cluster.scheduler_address,
                       "--worker-wait", "1.5", "--quiet"])
        waited = time.monotonic() - t0
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("ff-library: error:")]
    assert rc == 2 and len(err) == 1, err
    assert "no workers after 1.5 s" in err[0] and "dask worker" in err[0], err[0]
    assert 1.5 <= waited < 30.0, waited
    assert not lib.exists()

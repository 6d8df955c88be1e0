"""``ff-library``: build a motion library from a task grid on Dask, and show what it holds.

    ff-library build GRID.yaml --library PATH [--workers N | --serial | --scheduler tls://HOST:PORT
                     --tls-ca-file CA.pem --tls-cert CLIENT.pem --tls-key CLIENT.key]
                     [--no-continuation] [--roots R] [--dashboard] [--json]
    ff-library show --library PATH [--grid GRID.yaml] [--png map.png] [--limit N] [--json]

The library is the planner node's motion library (``ff_planner.library.store``, SQLite): point the node's
``library_path`` at the same file, with the same model preset/overrides (rows of other parameters
are invisible to it). With ``--scheduler`` the workers of that cluster must have this suite
installed (same version); they only compute, this command writes the file. A ``tls://`` scheduler
takes this client's certificate and key, signed by the cluster's CA (mutual TLS); a plain
``tcp://`` one works, with a warning: it is unencrypted and unauthenticated, and whoever reaches it
can run code on its workers (docs/security.md). The grid file may name the scheduler and the files
itself (keys ``scheduler``, ``tls_ca_file``, ``tls_cert``, ``tls_key``); the command line wins
(``--serial`` or ``--workers`` build here whatever the file says).

Exit codes: 0 done (infeasible tasks are an answer, not an error); 1 some tasks failed (re-run to
retry them); 2 bad input (one line on stderr saying what to change).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from ff_planner.library.cluster import DEFAULT_WORKER_WAIT, SchedulerSettings, merge
from ff_planner.library.grid import GridError, describe, expand, load_grid
from ff_planner.library.store import LibraryError, MotionLibrary, MotionRecord
from ff_planner.model.params import ParameterError, n_joints

GROUP_FIELDS = ("model", "params_hash", "objective", "uncertain", "steps", "coast")


# --- summaries --------------------------------------------------------------------------------
def group_of(r: MotionRecord) -> tuple:
    return (r.model, r.params_hash, r.objective, ",".join(sorted(r.uncertain)), r.steps, r.coast)


def summary(records: Sequence[MotionRecord]) -> list[dict[str, Any]]:
    """One row per (model, parameter set, objective, uncertain set, steps, coast)."""
    groups: dict[tuple, list[MotionRecord]] = defaultdict(list)
    for r in records:
        groups[group_of(r)].append(r)
    out = []
    for g, rs in sorted(groups.items(), key=lambda kv: kv[0]):
        st = Counter(r.status for r in rs)
        how = Counter(r.solved_how for r in rs if r.status == "solved")
        sens = [r.max_abs_sensitivity for r in rs if r.status == "solved" and r.max_abs_sensitivity is not None]
        err = [r.final_error for r in rs if r.status == "solved" and r.final_error is not None]
        out.append({
            **dict(zip(GROUP_FIELDS, g)), "tasks": len(rs), "solved": st["solved"],
            "robust": sum(1 for r in rs if r.status == "solved" and r.robust),
            "infeasible": st["infeasible"], "failed": st["failed"], "solved_how": dict(how),
            "max_abs_sensitivity_median": float(np.median(sens)) if sens else None,
            "max_abs_sensitivity_max": float(np.max(sens)) if sens else None,
            "final_error_max": float(np.max(err)) if err else None,
            "solve_time_total_s": float(sum(r.solve_time for r in rs if r.solved_how != "shift")),
            "reasons": dict(Counter(r.error_code for r in rs if r.status != "solved")),
        })
    return out


def _fmt(x: Optional[float], spec: str = ".2g") -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


def print_summary(rows: list[dict[str, Any]], records: Sequence[MotionRecord], limit: int,
                  missing: Optional[int], out=None) -> None:
    out = out or sys.stdout
    for s in rows:
        print(f"{s['model']}  params {s['params_hash'][:10]}  {s['objective']}  uncertain "
              f"[{s['uncertain']}]  steps {s['steps']}  coast {s['coast']:g} s", file=out)
        print(f"  tasks {s['tasks']}: solved {s['solved']} (robust {s['robust']}; how "
              f"{', '.join(f'{k} {v}' for k, v in sorted(s['solved_how'].items())) or '-'}), "
              f"infeasible {s['infeasible']}, failed {s['failed']}"
              + (f"  [{', '.join(f'{k} {v}' for k, v in s['reasons'].items())}]" if s['reasons'] else ""),
              file=out)
        print(f"  max |dq(tf)/dp|: median {_fmt(s['max_abs_sensitivity_median'])}, worst "
              f"{_fmt(s['max_abs_sensitivity_max'])}; worst |q(tf) - qf| {_fmt(s['final_error_max'])} rad; "
              f"planner time {s['solve_time_total_s']:.3g} s", file=out)
    if missing is not None:
        print(f"grid tasks not stored yet: {missing}", file=out)
    if limit <= 0 or not records:
        return
    print(f"\n{'q0':>16} {'qf':>16} {'tf':>6} {'status':>10} {'robust':>6} {'max|dq/dp|':>10} "
          f"{'|q-qf|':>8} {'how':>12} {'time s':>8}  reason", file=out)
    rs = sorted(records, key=lambda r: (r.model, r.tf, r.q0, r.qf))
    for r in rs[:limit]:
        q0 = ",".join(f"{x:.3g}" for x in r.q0)
        qf = ",".join(f"{x:.3g}" for x in r.qf)
        print(f"{q0:>16} {qf:>16} {r.tf:>6.3g} {r.status:>10} {('yes' if r.robust else 'no'):>6} "
              f"{_fmt(r.max_abs_sensitivity):>10} {_fmt(r.final_error):>8} {r.solved_how:>12} "
              f"{r.solve_time:>8.3g}  {r.reason[:60]}", file=out)
    if len(rs) > limit:
        print(f"... {len(rs) - limit} more (--limit)", file=out)


# --- the map ------------------------------------------------------------------------------------
def _xy(r: MotionRecord) -> tuple[float, float]:
    """Map position: move distance (rad; 2-DOF: Euclidean over joints) and move time (s)."""
    d = np.asarray(r.qf, float) - np.asarray(r.q0, float)
    return (float(d[0]) if d.size == 1 else float(np.linalg.norm(d))), float(r.tf)


def plot_map(records: Sequence[MotionRecord], path: str | Path, title: str = "") -> Path:
    """PNG map of the grid, one panel per group: solved (colour = log10 max |dq(tf)/dp|; square =
    continuation, circle = cold multistart, diamond = shifted copy), infeasible (red x), failed (grey)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups: dict[tuple, list[MotionRecord]] = defaultdict(list)
    for r in records:
        groups[group_of(r)].append(r)
    n = max(1, len(groups))
    fig, axes = plt.subplots(1, n, figsize=(6.0 * n, 5.4), squeeze=False)
    fig.subplots_adjust(bottom=0.24, top=0.86)
    sc = None
    for ax, (g, rs) in zip(axes[0], sorted(groups.items(), key=lambda kv: kv[0])):
        # shift copies sit on top of the motion they copy: draw solved ones first, copies smaller
        for how, marker in (("cold", "o"), ("continuation", "s"), ("warm", "s"), ("shift", "D")):
            sel = [r for r in rs if r.status == "solved" and r.solved_how == how]
            if not sel:
                continue
            xy = np.array([_xy(r) for r in sel])
            c = np.log10(np.clip([r.max_abs_sensitivity if r.max_abs_sensitivity is not None else 1.0
                                  for r in sel], 1e-16, 1e2))
            sc = ax.scatter(xy[:, 0], xy[:, 1], c=c, cmap="viridis", vmin=-16, vmax=0, marker=marker,
                            s=25 if how == "shift" else 70, edgecolors="k", linewidths=0.5,
                            label=f"solved ({how}) {len(sel)}", zorder=3 if how != "shift" else 2)
            nr = [r for r in sel if not r.robust]
            if nr:
                xy2 = np.array([_xy(r) for r in nr])
                ax.scatter(xy2[:, 0], xy2[:, 1], facecolors="none", edgecolors="orange", s=140,
                           linewidths=1.2, zorder=4)
        for status, kw in (("infeasible", dict(marker="x", color="red", s=60)),
                           ("failed", dict(marker="s", color="0.6", s=50))):
            sel = [r for r in rs if r.status == status]
            if sel:
                xy = np.array([_xy(r) for r in sel])
                ax.scatter(xy[:, 0], xy[:, 1], label=f"{status} {len(sel)}", zorder=3, **kw)
        ax.set_xlabel("move qf − q0 (rad)" if n_joints(g[0]) == 1 else "move ‖qf − q0‖ (rad)")
        ax.set_ylabel("move time tf (s)")
        ax.set_title(f"{g[0]} {g[2]} [{g[3]}] N={g[4]}", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=3, frameon=False)
    if sc is not None:
        cb = fig.colorbar(sc, ax=list(axes[0]), shrink=0.85)
        cb.set_label("log10 max |dq(tf)/dp|  (orange ring: not robust)")
    if title:
        fig.suptitle(title, fontsize=10)
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


# --- commands -------------------------------------------------------------------------------------
def cmd_build(a: argparse.Namespace) -> int:
    from ff_planner.library.build import build_library

    grid = expand(load_grid(a.grid))
    info = describe(grid)
    settings = scheduler_settings(a, grid.spec.scheduler)
    if a.dashboard and (settings or a.serial):
        raise GridError("--dashboard only applies to the LocalCluster this command starts")
    if settings is not None:
        settings.check()
        note = settings.warning()
        if note:
            print(f"ff-library: warning: {note}", file=sys.stderr)
    if not a.quiet:
        local = f"a LocalCluster on 127.0.0.1 with {a.workers or 'one per core'} workers"
        where = settings.parsed.url if settings else ("this process" if a.serial else local)
        print(f"ff-library: {info['tasks']} tasks ({info['distinct_motions']} distinct motions, "
              f"{info['shift_copies']} shifted copies), continuation tree depth {info['tree_depth']}, "
              f"on {where}", file=sys.stderr)
    client = cluster = None
    if a.dashboard:
        import importlib.util

        from ff_planner.library.build import start_local_cluster

        cluster, client = start_local_cluster(a.workers, dashboard=True)
        if importlib.util.find_spec("bokeh") is None:
            print("ff-library: the Dask dashboard needs bokeh (pip install bokeh); building without it",
                  file=sys.stderr)
        else:
            print(f"ff-library: dashboard at {cluster.dashboard_link}", file=sys.stderr)
    try:
        rep = build_library(grid, a.library, workers=a.workers, scheduler=settings, client=client,
                            serial=a.serial, continuation=not a.no_continuation, roots=a.roots,
                            local_starts=a.local_starts, progress=not a.quiet,
                            worker_wait=a.worker_wait)
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    d = rep.to_dict()
    if a.json:
        print(json.dumps(d, indent=2))
    else:
        print(f"library {rep.library}: {rep.solved} solved, {rep.infeasible} infeasible, {rep.failed} failed "
              f"this run ({rep.stored_before} stored before); distinct motions planned {rep.distinct_solved} "
              f"({', '.join(f'{k} {v}' for k, v in sorted(rep.how.items())) or '-'}); {rep.wall_time:.1f} s, "
              f"{rep.tasks_per_minute:.1f} tasks/min on {rep.workers or 'no'} workers ({rep.scheduler})")
        for e in rep.worker_errors[:5]:
            print(f"  worker error: {e}")
    return 1 if rep.failed else 0


def scheduler_settings(a: argparse.Namespace, from_grid: Optional[SchedulerSettings]) -> Optional[SchedulerSettings]:
    """The scheduler to build on: the command line's, else the grid file's unless --serial or
    --workers ask for a build here; None = build here."""
    if a.serial or a.workers is not None:
        from_grid = None
    return merge(from_grid, a.scheduler, a.tls_ca_file, a.tls_cert, a.tls_key)


def cmd_show(a: argparse.Namespace) -> int:
    if not Path(a.library).expanduser().is_file():
        raise LibraryError(f"no motion library at {a.library}; build one with 'ff-library build'")
    with MotionLibrary(a.library) as lib:
        records = lib.records()
        missing = None
        if a.grid:
            grid = expand(load_grid(a.grid))
            keys = {t.key for t in grid.tasks}
            records = [r for r in records if r.task_key in keys]
            missing = len(keys) - len(records)
    rows = summary(records)
    if a.json:
        print(json.dumps({"library": str(a.library), "groups": rows, "missing": missing}, indent=2))
    else:
        if not records:
            print(f"{a.library}: no motions stored" + (" for this grid" if a.grid else ""))
        print_summary(rows, records, a.limit, missing)
    if a.png:
        if not records:
            raise LibraryError("nothing to plot: the library holds no matching motions")
        p = plot_map(records, a.png, title=f"motion library {Path(a.library).name}")
        print(f"map written to {p}", file=sys.stderr)
    return 0


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="ff-library", description=__doc__.replace("``", ""),
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    b = sub.add_parser("build", help="solve every task of a grid into a motion library (Dask)")
    b.add_argument("grid", help="grid YAML file (see ff_planner/library/grid.py)")
    b.add_argument("--library", required=True, help="motion library file (SQLite), created if missing")
    b.add_argument("--workers", type=int, default=None,
                   help="LocalCluster worker processes (default: one per core)")
    b.add_argument("--scheduler", default=None,
                   help="use an existing Dask scheduler: tls://HOST:PORT (with the three --tls-* files) or "
                        "tcp://HOST:PORT (unencrypted, unauthenticated: warns)")
    b.add_argument("--tls-ca-file", default=None, help="tls://: the CA that signed the cluster's certificates (PEM)")
    b.add_argument("--tls-cert", default=None, help="tls://: this client's certificate, signed by that CA (PEM)")
    b.add_argument("--tls-key", default=None, help="tls://: this client's private key (PEM, unencrypted)")
    b.add_argument("--worker-wait", type=float, default=DEFAULT_WORKER_WAIT, metavar="S",
                   help="--scheduler: give up when the cluster has no worker after S seconds "
                        f"(default {DEFAULT_WORKER_WAIT:g})")
    b.add_argument("--serial", action="store_true", help="no Dask: solve in this process")
    b.add_argument("--no-continuation", action="store_true",
                   help="solve every task cold (multistart), ignoring neighbours")
    b.add_argument("--local-starts", type=int, default=16,
                   help="continuation: starts from the neighbour's currents and perturbations of them")
    b.add_argument("--roots", type=int, default=1, help="cold-started subtrees (more early parallelism)")
    b.add_argument("--dashboard", action="store_true", help="LocalCluster dashboard on 127.0.0.1 (needs bokeh)")
    b.add_argument("--quiet", action="store_true", help="no progress bar")
    b.add_argument("--json", action="store_true", help="print the build report as JSON")
    b.set_defaults(fn=cmd_build)
    s = sub.add_parser("show", help="summary table and PNG map of a motion library")
    s.add_argument("--library", required=True)
    s.add_argument("--grid", default=None, help="only this grid's tasks (and count the missing ones)")
    s.add_argument("--png", default=None, help="write a PNG map of the grid here")
    s.add_argument("--limit", type=int, default=40, help="rows of the per-task table (0 = none)")
    s.add_argument("--json", action="store_true")
    s.set_defaults(fn=cmd_show)
    return ap


def main(argv: Optional[Sequence[str]] = None) -> int:
    a = parser().parse_args(argv)
    if getattr(a, "workers", None) is not None and a.workers < 1:
        print("ff-library: error: --workers must be >= 1", file=sys.stderr)
        return 2
    if getattr(a, "scheduler", None) and (getattr(a, "serial", False) or getattr(a, "workers", None)):
        print("ff-library: error: give --scheduler, --serial or --workers, one of them", file=sys.stderr)
        return 2
    try:
        return int(a.fn(a))
    except (GridError, LibraryError, ParameterError, ValueError, OSError) as exc:
        print(f"ff-library: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("ff-library: interrupted; what was stored stays stored (re-run to resume)", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

"""ff-library build on a TLS-only Dask scheduler (mutual TLS, a CA made here with the openssl CLI):
built with the right certificate; refused, with one line and no file written, without one, with
one from another CA, over plain tcp://; a plain tcp:// scheduler still builds, with one warning.

Scheduler and worker run in this process on 127.0.0.1 (their own event loop in a thread)."""
from __future__ import annotations

import asyncio
import contextlib
import json
import os
import shutil
import socket
import ssl
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Optional

import psutil  # a dependency of dask.distributed
import pytest
import yaml

from ff_planner.cli.library import main as cli_main
from ff_planner.library.store import MotionLibrary

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command")

REPO = Path(__file__).resolve().parents[3]
# the shipped small grid, cut to two motions (0 -> 0.5 rad and 0 -> 1 rad in 1 s)
GRID = {**yaml.safe_load((REPO / "config" / "grid_1dof_small.yaml").read_text()),
        "q0": 0.0, "qf": [0.5, 1.0], "tf": [1.0]}
N_TASKS = 2
BUILD_S = 60.0      # s, bound on one two-task build on a loaded 2-core machine (seen: about 1 s)


# --- certificates ---------------------------------------------------------------------------------
@dataclass
class Pki:
    """PEM files: the cluster's CA and its scheduler, worker, client pairs; a foreign CA and a
    client pair it signed."""

    dir: Path

    def __getattr__(self, name: str) -> str:      # pki.client_pem -> DIR/client.pem
        stem, _, ext = name.rpartition("_")
        if not stem or ext not in ("pem", "key"):
            raise AttributeError(name)
        return str(self.dir / f"{stem}.{ext}")


def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=60)


def make_pki(d: Path) -> Pki:
    """Two self-signed CAs (P-256, valid 2 days) and leaf certificates signed by them."""
    d.mkdir(parents=True, exist_ok=True)
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes"]
    for ca in ("ca", "other"):
        _openssl("req", "-x509", "-new", *ec, "-keyout", f"{ca}.key", "-out", f"{ca}.pem", "-days", "2",
                 "-subj", f"/CN=ff-test-{ca}", "-addext", "basicConstraints=critical,CA:TRUE",
                 "-addext", "keyUsage=critical,keyCertSign,cRLSign", cwd=d)
    (d / "leaf.ext").write_text("basicConstraints=CA:FALSE\nkeyUsage=critical,digitalSignature\n"
                                "extendedKeyUsage=serverAuth,clientAuth\nsubjectAltName=IP:127.0.0.1\n")
    for ca, leaf in (("ca", "scheduler"), ("ca", "worker"), ("ca", "client"), ("other", "rogue")):
        _openssl("req", "-new", *ec, "-keyout", f"{leaf}.key", "-out", f"{leaf}.csr", "-subj", f"/CN={leaf}", cwd=d)
        _openssl("x509", "-req", "-in", f"{leaf}.csr", "-CA", f"{ca}.pem", "-CAkey", f"{ca}.key",
                 "-CAcreateserial", "-out", f"{leaf}.pem", "-days", "2", "-extfile", "leaf.ext", cwd=d)
    return Pki(d)


@pytest.fixture(scope="module")
def pki(tmp_path_factory) -> Pki:
    return make_pki(tmp_path_factory.mktemp("pki"))


# --- an in-process cluster ---------------------------------------------------------------------------
@contextlib.contextmanager
def cluster(protocol: str, scheduler_security: Any = None, worker_security: Any = None) -> Iterator[str]:
    """A scheduler and one single-threaded worker on 127.0.0.1 (``protocol`` tls or tcp), served
    by an event loop in a thread; yields the scheduler's address."""
    from distributed import Scheduler, Worker

    loop = asyncio.new_event_loop()
    started = threading.Event()
    info: dict[str, Any] = {}

    async def serve() -> None:
        stop = info["stop"] = asyncio.Event()
        async with Scheduler(host=f"{protocol}://127.0.0.1", port=0, security=scheduler_security,
                             dashboard=False, dashboard_address="127.0.0.1:0") as s:
            async with Worker(s.address, host=f"{protocol}://127.0.0.1", security=worker_security,
                              nthreads=1, dashboard=False, dashboard_address="127.0.0.1:0"):
                info["address"] = s.address
                started.set()
                await stop.wait()

    def run() -> None:
        try:
            loop.run_until_complete(serve())
        except BaseException as exc:  # noqa: BLE001 - reported to the test below
            info["error"] = exc
        finally:
            started.set()

    thread = threading.Thread(target=run, name=f"dask-{protocol}", daemon=True)
    thread.start()
    assert started.wait(60), "the cluster did not start within 60 s"
    if "error" in info:
        raise info["error"]
    try:
        yield info["address"]
    finally:
        loop.call_soon_threadsafe(info["stop"].set)
        thread.join(30)
        assert not thread.is_alive(), "the cluster did not stop within 30 s"
        loop.close()


@pytest.fixture(scope="module")
def tls_scheduler(pki) -> Iterator[str]:
    from distributed import Security

    s = Security(tls_ca_file=pki.ca_pem, tls_scheduler_cert=pki.scheduler_pem,
                 tls_scheduler_key=pki.scheduler_key, require_encryption=True)
    w = Security(tls_ca_file=pki.ca_pem, tls_worker_cert=pki.worker_pem, tls_worker_key=pki.worker_key,
                 require_encryption=True)
    with cluster("tls", s, w) as address:
        yield address


# --- helpers ----------------------------------------------------------------------------------------
def _grid_file(d: Path, **keys: Any) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    p = d / "grid.yaml"
    p.write_text(yaml.safe_dump({**GRID, **keys}))
    return p


def _build(capsys, *args: str) -> tuple[int, str, list[str]]:
    """ff-library build ARGS --quiet: exit code, stdout, stderr lines."""
    capsys.readouterr()
    rc = cli_main(["build", *args, "--quiet"])
    cap = capsys.readouterr()
    return rc, cap.out, [ln for ln in cap.err.splitlines() if ln.strip()]


def _refused(rc: int, err: list[str], library: Path, *words: str) -> None:
    """Exit 2, one error line naming ``words``, no library file."""
    errors = [ln for ln in err if ln.startswith("ff-library: error:")]
    assert rc == 2 and len(errors) == 1 and len(err) <= 2, err
    for w in words:
        assert w in errors[0], (w, errors[0])
    assert not [p for p in library.parent.iterdir() if p.name.startswith(library.name)], "something was written"


def _tls_args(pki: Pki, cert: str = "client", ca: str = "ca") -> list[str]:
    return ["--tls-ca-file", str(pki.dir / f"{ca}.pem"), "--tls-cert", str(pki.dir / f"{cert}.pem"),
            "--tls-key", str(pki.dir / f"{cert}.key")]


def _raw_tls_reply(address: str, ca: str, cert: Optional[str], key: Optional[str]) -> bytes:
    """Bytes the scheduler sends a raw TLS client within 10 s (b"" when it closes or refuses)."""
    host, port = address.removeprefix("tls://").rsplit(":", 1)
    ctx = ssl.create_default_context(ssl.Purpose.SERVER_AUTH, cafile=ca)
    ctx.check_hostname = False
    if cert:
        ctx.load_cert_chain(cert, key)
    data = b""
    with socket.create_connection((host, int(port)), timeout=10) as raw:
        try:
            with ctx.wrap_socket(raw) as tls:
                tls.settimeout(10)
                data = tls.recv(64)
        except (ssl.SSLError, ConnectionError, TimeoutError):
            pass
    return data


# --- tests --------------------------------------------------------------------------------------------
@pytest.mark.integration
def test_build_on_a_tls_only_scheduler_with_the_right_certificate(pki, tls_scheduler, tmp_path, capsys):
    assert tls_scheduler.startswith("tls://127.0.0.1:")
    lib = tmp_path / "lib.sqlite"
    t0 = time.monotonic()
    rc, out, err = _build(capsys, str(_grid_file(tmp_path)), "--library", str(lib), "--scheduler", tls_scheduler,
                          *_tls_args(pki), "--json")
    took = time.monotonic() - t0
    assert rc == 0, err
    assert not any("warning" in ln for ln in err), err
    rep = json.loads(out)
    assert rep["scheduler"] == tls_scheduler and rep["workers"] == 1
    assert rep["solved"] + rep["infeasible"] == N_TASKS and rep["failed"] == 0 and rep["distinct_solved"] == N_TASKS
    with MotionLibrary(lib) as m:
        assert sorted(r.status for r in m.records()) == ["solved"] * N_TASKS
    assert took < BUILD_S, took
    # everything this process listens on (scheduler, worker, their HTTP servers) is on loopback
    listening = [c.laddr for c in psutil.Process().net_connections(kind="inet") if c.status == psutil.CONN_LISTEN]
    assert len(listening) >= 2 and all(a.ip == "127.0.0.1" for a in listening), listening


@pytest.mark.integration
def test_the_grid_file_names_the_scheduler_and_its_certificates(pki, tls_scheduler, tmp_path, capsys, monkeypatch):
    rel = os.path.relpath(pki.dir, tmp_path / "grids")
    grid = _grid_file(tmp_path / "grids", scheduler=tls_scheduler, tls_ca_file=f"{rel}/ca.pem",
                      tls_cert=f"{rel}/client.pem", tls_key=f"{rel}/client.key")
    monkeypatch.chdir(tmp_path)          # relative names are taken from the grid file's folder
    lib = tmp_path / "lib.sqlite"
    rc, out, err = _build(capsys, str(grid), "--library", str(lib), "--json")
    assert rc == 0, err
    assert json.loads(out)["scheduler"] == tls_scheduler
    with MotionLibrary(lib) as m:
        assert len(m.records()) == N_TASKS
    # the file's certificate replaced by a foreign one on the command line: refused
    lib2 = tmp_path / "lib2.sqlite"
    rc, _, err = _build(capsys, str(grid), "--library", str(lib2), "--tls-cert", pki.rogue_pem,
                        "--tls-key", pki.rogue_key)
    _refused(rc, err, lib2, "refused")


@pytest.mark.integration
def test_refused_without_a_certificate(pki, tls_scheduler, tmp_path, capsys):
    grid = str(_grid_file(tmp_path))
    lib = tmp_path / "lib.sqlite"
    # this command asks for the files before it connects
    rc, _, err = _build(capsys, grid, "--library", str(lib), "--scheduler", tls_scheduler)
    _refused(rc, err, lib, "--tls-ca-file", "--tls-cert", "--tls-key")
    rc, _, err = _build(capsys, grid, "--library", str(lib), "--scheduler", tls_scheduler,
                        "--tls-ca-file", pki.ca_pem)
    _refused(rc, err, lib, "--tls-cert", "--tls-key")
    # plain tcp to the TLS port: the scheduler drops it
    rc, _, err = _build(capsys, grid, "--library", str(lib), "--scheduler", tls_scheduler.replace("tls://", "tcp://"))
    _refused(rc, err, lib, "cannot use the Dask scheduler")
    # the scheduler itself refuses a TLS client that shows no certificate, and answers one that does
    assert _raw_tls_reply(tls_scheduler, pki.ca_pem, None, None) == b""
    assert len(_raw_tls_reply(tls_scheduler, pki.ca_pem, pki.client_pem, pki.client_key)) > 0


@pytest.mark.integration
def test_refused_with_a_certificate_from_another_ca(pki, tls_scheduler, tmp_path, capsys):
    grid = str(_grid_file(tmp_path))
    lib = tmp_path / "lib.sqlite"
    # trusts the scheduler, shows a certificate the cluster's CA did not sign: the scheduler refuses
    rc, _, err = _build(capsys, grid, "--library", str(lib), "--scheduler", tls_scheduler, *_tls_args(pki, "rogue"))
    _refused(rc, err, lib, "refused", tls_scheduler)
    # all from another CA: neither side trusts the other
    rc, _, err = _build(capsys, grid, "--library", str(lib), "--scheduler", tls_scheduler,
                        *_tls_args(pki, "rogue", ca="other"))
    _refused(rc, err, lib, "refused")
    assert _raw_tls_reply(tls_scheduler, pki.ca_pem, pki.rogue_pem, pki.rogue_key) == b""
    # and the right certificate still builds afterwards
    rc, _, err = _build(capsys, grid, "--library", str(lib), "--scheduler", tls_scheduler, *_tls_args(pki))
    assert rc == 0, err


@pytest.mark.integration
def test_a_plain_tcp_scheduler_builds_with_one_warning(tmp_path, capsys):
    with cluster("tcp") as address:
        assert address.startswith("tcp://127.0.0.1:")
        lib = tmp_path / "lib.sqlite"
        rc, out, err = _build(capsys, str(_grid_file(tmp_path)), "--library", str(lib), "--scheduler", address,
                              "--json")
    assert rc == 0, err
    warnings = [ln for ln in err if ln.startswith("ff-library: warning:")]
    assert len(warnings) == 1 and "unencrypted and unauthenticated" in warnings[0], err
    assert json.loads(out)["solved"] == N_TASKS


def test_bad_scheduler_settings_give_one_line_and_write_nothing(pki, tmp_path, capsys):
    grid = str(_grid_file(tmp_path))
    lib = tmp_path / "lib.sqlite"
    port = "tls://127.0.0.1:9"      # never contacted: each case is refused before connecting
    encrypted = tmp_path / "encrypted.key"
    _openssl("ec", "-in", pki.client_key, "-out", str(encrypted), "-aes256", "-passout", "pass:secret", cwd=tmp_path)
    cases = [
        (["--scheduler", "tcp://127.0.0.1:9", *_tls_args(pki)], ["plain tcp://", "tls://127.0.0.1:9"]),
        ([*_tls_args(pki)], ["give the scheduler too"]),
        (["--scheduler", port, *_tls_args(pki), "--tls-cert", str(tmp_path / "none.pem")], ["--tls-cert", "no file"]),
        (["--scheduler", port, "--tls-ca-file", pki.ca_pem, "--tls-cert", pki.client_pem, "--tls-key", pki.rogue_key],
         ["matching"]),
        (["--scheduler", port, "--tls-ca-file", pki.client_key, "--tls-cert", pki.client_pem,
          "--tls-key", pki.client_key], ["--tls-ca-file"]),
        (["--scheduler", port, "--tls-ca-file", pki.ca_pem, "--tls-cert", pki.client_pem, "--tls-key", str(encrypted)],
         ["encrypted"]),
        (["--scheduler", "ucx://127.0.0.1:9"], ["scheme 'ucx'"]),
        (["--scheduler", "tls://127.0.0.1"], ["HOST:PORT"]),
        (["--scheduler", port, "--workers", "2"], ["one of them"]),
        (["--serial", "--tls-cert", pki.client_pem], ["give the scheduler too"]),
    ]
    for args, words in cases:
        rc, _, err = _build(capsys, grid, "--library", str(lib), *args)
        _refused(rc, err, lib, *words)
    # the same checks on the grid file's keys
    for keys, words in (({"tls_cert": pki.client_pem}, ["without scheduler"]),
                        ({"scheduler": "http://127.0.0.1:9"}, ["scheme 'http'"]),
                        ({"scheduler": 8786}, ["expected text"])):
        rc, _, err = _build(capsys, str(_grid_file(tmp_path / "bad", **keys)), "--library", str(lib))
        _refused(rc, err, lib, *words)

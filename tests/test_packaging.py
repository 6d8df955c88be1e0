"""The built wheel, installed into a fresh virtual environment without the planner's extras.

The wheel is built from this checkout (``pip wheel --no-deps --no-build-isolation``) every run, so
it always carries the checkout's Python files and configs. The slow part, generating and compiling
the ff_msgs interfaces with rosidl and CMake (4-5 min on a loaded 2-core machine), happens in a
CMake build folder kept between runs (``build/test-wheel``, scikit-build-core's ``build-dir``) and
made afresh whenever the interface inputs change (their hash: the .msg/.srv/.action files,
CMakeLists.txt, package.xml, pyproject.toml, the Python version, the folder's own path, which
CMake records); CMake itself rebuilds whatever
changed in between. With that folder in place the build takes about 10 s. The fresh environment gets the wheel
(``pip install --no-deps``) and, as its installed dependencies, links to the test environment's
packages except the optional ones (numba, llvmlite, scipy, pebble, dask, distributed, matplotlib,
rosbags, mcap) and the checkout's own editable install: what a bridge-only robot PC would have
after ``pip install ff-suite`` (no network needed). ``pip check`` confirms that this is every
base requirement of the wheel. Everything runs outside the checkout, with the ROS library path
set up afresh (no PYTHONPATH, LD_LIBRARY_PATH or bootstrap marker inherited).
"""
from __future__ import annotations

import fcntl
import hashlib
import importlib.metadata as md
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
import zipfile
from email.parser import Parser
from pathlib import Path

import pytest
import yaml

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[1]
#: distributions a bridge-only install must not need (and the checkout's own install)
OPTIONAL = ("numba", "llvmlite", "scipy", "pebble", "dask", "distributed", "matplotlib", "rosbags",
            "mcap", "mcap-ros2-support", "ff-suite")
HEAVY_MODULES = ("numba", "llvmlite", "scipy", "pebble", "dask", "distributed", "matplotlib", "rosbags")
EXTRAS = ("planner", "cluster", "plot", "sim", "record", "all")
PY = f"python{sys.version_info.major}.{sys.version_info.minor}"


def _site(prefix: Path) -> Path:
    return prefix / "lib" / PY / "site-packages"


def _link_tree(src: Path, dst: Path, skip, deep: tuple[str, ...] = ()) -> None:
    """Symlink each entry of ``src`` into ``dst`` (a real folder) unless ``skip(name)``; the
    folders named in ``deep`` become real folders linked entry by entry (the wheel installs into
    them, which must never write through a link into the test environment)."""
    dst.mkdir(parents=True, exist_ok=True)
    for entry in src.iterdir():
        if skip(entry.name):
            continue
        if entry.name in deep and entry.is_dir():
            _link_tree(entry, dst / entry.name, skip, tuple(d for d in deep if d != entry.name) + ("*",))
        elif "*" in deep and entry.is_dir():
            _link_tree(entry, dst / entry.name, skip, deep)
        else:
            (dst / entry.name).symlink_to(entry)


#: the CMake build folder of the interfaces, kept between runs (build/ is ignored by git); ``./run
#: setup`` builds the editable install in it, so a fresh checkout's wheel build reuses that work
BUILD_DIR = REPO / "build" / "cmake"


def interface_key() -> str:
    """Hash of everything the generated ff_msgs interfaces are built from."""
    h = hashlib.sha256(f"{sys.version}\0{BUILD_DIR}".encode())     # CMake keeps absolute paths
    msgs = REPO / "ff_msgs_py"
    files = sorted([*msgs.glob("msg/*"), *msgs.glob("srv/*"), *msgs.glob("action/*"),
                    msgs / "CMakeLists.txt", msgs / "package.xml", REPO / "pyproject.toml"])
    for f in files:
        h.update(str(f.relative_to(REPO)).encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()[:16]


def _cache_here() -> bool:
    """Whether BUILD_DIR's CMake cache was made for this folder (one that ``./run setup`` made in
    this checkout; CMake refuses a cache made elsewhere)."""
    cache = BUILD_DIR / "CMakeCache.txt"
    if not cache.is_file():
        return False
    for line in cache.read_text(errors="replace").splitlines():
        if line.startswith("CMAKE_CACHEFILE_DIR:"):
            return Path(line.split("=", 1)[1]).resolve() == BUILD_DIR.resolve()
    return False


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    BUILD_DIR.parent.mkdir(parents=True, exist_ok=True)
    with open(BUILD_DIR.parent / "test-wheel.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)           # one build at a time in this checkout
        key, stamp = interface_key(), BUILD_DIR / "ff-interface-key"
        if BUILD_DIR.exists() and (stamp.read_text() != key if stamp.is_file() else not _cache_here()):
            shutil.rmtree(BUILD_DIR)               # other interface inputs or folder: from scratch
        t0 = time.monotonic()
        proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
                               "-C", f"build-dir={BUILD_DIR}", "-w", str(out), str(REPO)],
                              capture_output=True, text=True, timeout=900)
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
        stamp.write_text(key)
    print(f"wheel built in {time.monotonic() - t0:.1f} s")
    (whl,) = out.glob("ff_suite-*.whl")
    return whl


def _venv(wheel: Path, prefix: Path, without: tuple[str, ...]) -> Path:
    """A new venv at ``prefix`` with the wheel and links to this environment's packages except
    the distributions ``without``; returns ``prefix``."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(prefix)], check=True, timeout=120)
    ours = _site(Path(sys.prefix))
    drop = {"ff_msgs", "__pycache__"} | {p.name for p in ours.glob("_editable_skbc_*")} \
        | {p.name for p in ours.glob("ff_msgs-*.egg-info")}
    for name in without:
        try:
            files = md.distribution(name).files or []
        except md.PackageNotFoundError:
            continue
        drop |= {Path(f).parts[0] for f in files if Path(f).parts and Path(f).parts[0] != ".."}
    _link_tree(ours, _site(prefix), lambda n: n in drop)
    here = Path(sys.prefix)      # the ROS wheels' shared libraries and ament index, without ff_msgs'
    _link_tree(here / "lib", prefix / "lib", lambda n: n == PY or n.startswith("libff_msgs"))
    _link_tree(here / "share", prefix / "share", lambda n: n == "ff_msgs", deep=("ament_index",))
    proc = subprocess.run([sys.executable, "-m", "pip", "--python", str(prefix / "bin" / "python"), "install",
                           "-q", "--no-deps", "--no-index", str(wheel)], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return prefix


@pytest.fixture(scope="module")
def fresh(wheel, tmp_path_factory) -> Path:
    """The wheel with its base dependencies only (a bridge-only robot PC)."""
    return _venv(wheel, tmp_path_factory.mktemp("venv") / "robot-pc", OPTIONAL)


@pytest.fixture(scope="module")
def full(wheel, tmp_path_factory) -> Path:
    """The wheel with every extra's dependencies (what ``pip install "ff-suite[all]"`` gives)."""
    return _venv(wheel, tmp_path_factory.mktemp("venv") / "workstation", ("ff-suite",))


def _run(prefix: Path, args: list[str], cwd: Path, timeout: float = 120.0) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "LD_LIBRARY_PATH", "_ROS_WHEELS_BOOTSTRAP_COMPLETE", "VIRTUAL_ENV")}
    env["PATH"] = f"{prefix / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def test_the_wheel_ships_every_config_and_keeps_the_optional_dependencies_in_extras(wheel):
    with zipfile.ZipFile(wheel) as z:
        for path in sorted((REPO / "config").glob("*.yaml")):
            assert z.read(f"ff_msgs_py/config/{path.name}") == path.read_bytes(), path.name
        (meta_name,) = [n for n in z.namelist() if n.endswith(".dist-info/METADATA")]
        meta = Parser().parsestr(z.read(meta_name).decode())
    requires = meta.get_all("Requires-Dist") or []
    base = [r.split(";")[0].strip() for r in requires if "extra ==" not in r]
    assert base and not [r for r in base if any(r.lower().startswith(o) for o in HEAVY_MODULES)], base
    assert set(EXTRAS) <= set(meta.get_all("Provides-Extra") or [])
    planner = [r for r in requires if 'extra == "planner"' in r]
    assert any(r.startswith("numba") for r in planner) and any(r.startswith("pebble") for r in planner)
    assert any(r.startswith("dask") for r in requires if 'extra == "cluster"' in r)
    assert any(r.startswith("matplotlib") for r in requires if 'extra == "plot"' in r)


def test_a_bridge_only_install_satisfies_its_requirements_without_the_extras(fresh, tmp_path):
    proc = _run(fresh, [sys.executable, "-m", "pip", "--python", str(fresh / "bin" / "python"), "check"], tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    proc = _run(fresh, [str(fresh / "bin" / "python"), "-c", "import numba"], tmp_path)
    assert proc.returncode != 0 and "No module named 'numba'" in proc.stderr


def test_the_bridge_and_executor_import_and_answer_help_without_numba_dask_matplotlib(fresh, tmp_path):
    code = ("import sys, ff_hwbridge.ros.bridge_node, ff_executor.ros.executor_node, ff_msgs.msg; "
            f"heavy = [m for m in {HEAVY_MODULES!r} if m in sys.modules]; "
            "print(ff_hwbridge.__file__); print(ff_msgs.msg.__file__); print('heavy', heavy)")
    proc = _run(fresh, [str(fresh / "bin" / "python"), "-c", code], tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.splitlines()
    assert lines[0].startswith(str(_site(fresh))) and lines[1].startswith(str(_site(fresh))), lines
    assert lines[2] == "heavy []", lines
    for script in ("ff-hwbridge", "ff-epos"):
        proc = _run(fresh, [str(fresh / "bin" / script), "--help"], tmp_path)
        assert proc.returncode == 0, (script, proc.stdout[-2000:], proc.stderr[-2000:])
        assert "usage" in proc.stdout.lower(), (script, proc.stdout[-2000:])


def test_the_shipped_configs_load_from_the_installed_package(fresh, tmp_path):
    code = ("from ff_msgs_py.configs import config_dir, load_config, available; "
            "print(config_dir()); print(len(available())); print(load_config('planner')['ff_planner']"
            "['ros__parameters']['switch_grid'])")
    proc = _run(fresh, [str(fresh / "bin" / "python"), "-c", code], tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    folder, count, grid = proc.stdout.split()
    assert Path(folder) == _site(fresh) / "ff_msgs_py" / "config"
    assert int(count) == len(list((REPO / "config").glob("*.yaml")))
    want = yaml.safe_load((REPO / "config" / "planner.yaml").read_text())
    assert float(grid) == want["ff_planner"]["ros__parameters"]["switch_grid"]
    proc = _run(fresh, [str(fresh / "bin" / "ff-config"), "bridge_epos4_1dof.yaml"], tmp_path)
    assert proc.returncode == 0 and proc.stdout == (REPO / "config" / "bridge_epos4_1dof.yaml").read_text()
    proc = _run(fresh, [str(fresh / "bin" / "ff-bringup"), "--help"], tmp_path)
    assert proc.returncode == 0 and "--print-config" in proc.stdout, proc.stderr[-2000:]


def test_bringup_from_the_installed_wheel_prints_its_effective_config(full, tmp_path):
    proc = _run(full, [str(full / "bin" / "ff-bringup"), "--print-config", "--run-dir", str(tmp_path / "run")],
                tmp_path)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    printed = yaml.safe_load(proc.stdout)
    assert {"ros", "ff_planner", "ff_hwbridge", "ff_executor", "ff_sim_driver"} <= set(printed), list(printed)
    assert printed["run_dir"] == str(tmp_path / "run")
    proc = _run(full, [str(full / "bin" / "python"), "-c", "import ff_planner.ros.planner_node, numba"], tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]


def test_bringup_from_the_installed_wheel_runs_the_stack_executes_a_plan_and_stops_by_pid(full, tmp_path):
    """ff-bringup and ff-ctl of the fresh environment (no checkout on the path): the simulated stack
    without the planner node (its kernels would compile from scratch in the new environment, ~45 s),
    an ff-motion/1 file executed with live feedback, and the stack stopped by its PID (SIGTERM).
    The motion: +3 A for 0.3 s, -3 A for 0.2 s, coast; its rest position from this checkout's exact
    model (1.4 rad). How close the arm lands is the end-to-end tests' subject (timing under load);
    here: the goal succeeded and the arm went most of the way (a stack that did not apply the
    currents leaves it at q0 = 0)."""
    from ff_msgs_py.launch import free_domain_id, ros_environment
    from ff_planner.export.motion_file import FORMAT, verify_motion
    from ff_planner.model.params import MODELS, default_params

    motion = tmp_path / "move.json"
    p = default_params("arm1dof")
    doc = {"format": FORMAT, "model": "arm1dof", "params": {k: float(getattr(p, k)) for k in MODELS["arm1dof"].keys()},
           "q0": [0.0], "qf": [1.0], "tf": 0.9, "coast": 0.4, "step_times": [0.0, 0.3, 0.5],
           "currents": [[3.0], [-3.0]], "uncertain": [],
           "predicted": {"q_final": [1.0], "qd_final": [0.0], "sensitivities": {}}}
    motion.write_text(json.dumps(doc))
    rest = float(verify_motion(motion).rest_position[0])
    assert 1.0 < rest < 2.0, rest
    doc["qf"] = doc["predicted"]["q_final"] = [rest]
    motion.write_text(json.dumps(doc))
    domain = free_domain_id()
    ros = ros_environment(domain_id=domain, log_dir=str(tmp_path / "ros-log"), base={})
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "LD_LIBRARY_PATH", "_ROS_WHEELS_BOOTSTRAP_COMPLETE", "VIRTUAL_ENV")}
    env.update(ros, PATH=f"{full / 'bin'}{os.pathsep}{env.get('PATH', '')}")
    bringup = subprocess.Popen([str(full / "bin" / "ff-bringup"), "--no-planner", "--run-dir", str(tmp_path / "run")],
                               cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    try:
        reader = threading.Thread(target=lambda: lines.extend(iter(bringup.stdout.readline, "")), daemon=True)
        reader.start()
        end = time.monotonic() + 300
        while time.monotonic() < end and bringup.poll() is None and not any("ff-bringup: running" in x for x in lines):
            time.sleep(0.2)
        assert any(f"export ROS_DOMAIN_ID={domain} " in x for x in lines), "".join(lines)[-3000:]
        proc = subprocess.run([str(full / "bin" / "ff-ctl"), "execute", str(motion), "--tolerance", "10"],
                              cwd=tmp_path, env=env, capture_output=True, text=True, timeout=180)
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
        assert "execute succeeded" in proc.stdout and proc.stdout.count("  t = ") >= 3, proc.stdout[-3000:]
        settled = re.search(r"settled at \[([-0-9.e]+)\] rad", proc.stdout)
        assert settled and float(settled.group(1)) > 0.5 * rest, proc.stdout[-3000:]
    finally:
        if bringup.poll() is None:
            os.kill(bringup.pid, signal.SIGTERM)
        try:
            code = bringup.wait(60)
        except subprocess.TimeoutExpired:
            bringup.kill()
            code = bringup.wait(10)
    out = "".join(lines)
    assert code == 0, out[-3000:]
    assert "ff-bringup: stopped" in out and "died" not in out, out[-3000:]

"""Shared fixtures: a per-run loopback-only ROS environment for this test process and its children."""
from __future__ import annotations

import os
import sys
import tempfile

import pytest

# With PYTHONDONTWRITEBYTECODE set, every run would compile the suite's modules again and rewrite
# the asserts of every test module (about half of the library suite's collection time, 14 s ->
# 7 s measured): the suite keeps its bytecode in __pycache__ (ignored by git).
sys.dont_write_bytecode = False

# The tests' processes talk DDS over UDP on loopback only (Fast DDS's builtin transports; set
# before any participant is created, inherited by every process the tests start): the tests kill
# processes on purpose, and a killed process leaves its shared-memory segments behind.
os.environ.setdefault("FASTDDS_BUILTIN_TRANSPORTS", "UDPv4")


#: pytest-xdist workers for the library suite run alone (``-m "not integration"``): its cases are
#: short and independent, and half their time is spent waiting (timers, threads, SYNC). A run that
#: includes the integration tests stays in one process: they start processes whose timing a
#: second worker would disturb. ``-n 0`` (or ``-p no:xdist``) runs the library suite in one process.
LIBRARY_WORKERS = 2


@pytest.hookimpl(tryfirst=True)
def pytest_cmdline_main(config: pytest.Config) -> None:
    if (config.pluginmanager.hasplugin("xdist") and config.getoption("numprocesses", None) is None
            and config.getoption("markexpr").strip() == "not integration"
            and not config.getoption("collectonly") and not os.environ.get("PYTEST_XDIST_WORKER")):
        config.option.numprocesses = LIBRARY_WORKERS
        if config.getoption("dist") == "no":
            config.option.dist = "worksteal"       # an idle worker takes cases from a busy one


_USED_DOMAINS: set[int] = set()


@pytest.fixture(scope="module")
def ros_env() -> dict[str, str]:
    """Environment for child processes; also applied to this process (rclpy in tests).

    Each test module gets its own ROS_DOMAIN_ID (and log folder), one that no other process on the
    machine uses: nodes left over by one module, or another test run in parallel, can then never
    answer, or crowd the discovery ports of, this one.
    """
    from ff_msgs_py.launch import apply_ros_environment, free_domain_id, ros_environment

    log_dir = tempfile.mkdtemp(prefix="ff-test-roslog-")
    domain = free_domain_id(exclude=_USED_DOMAINS)   # not used by any process on this machine
    _USED_DOMAINS.add(domain)
    env = ros_environment(domain_id=domain, log_dir=log_dir)
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env["PYTHONPATH"] = os.pathsep.join(p for p in (repo, env.get("PYTHONPATH", "")) if p)
    apply_ros_environment(env)
    return env


_ROS_VARS = ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_DOMAIN_ID", "ROS_LOG_DIR")


@pytest.fixture(autouse=True)
def _restore_ros_settings():
    """A test (e.g. a bring-up stack) may point this process at its own ROS domain: undo that."""
    saved = {k: os.environ.get(k) for k in _ROS_VARS}
    yield
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v


@pytest.fixture
def rclpy_node(ros_env):
    """An rclpy context + node for calling services/actions from the test process."""
    import rclpy
    from rclpy.node import Node

    from ff_msgs_py.launch import apply_ros_environment

    apply_ros_environment(ros_env)
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = Node("ff_test_client", context=ctx)
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)


@pytest.fixture(scope="session")
def robust_plan_1dof():
    """The canonical robust plan: 1-DOF table 2 arm, 0 → 1 rad in 1 s, pv, pc, pt uncertain, N = 5.

    Planned once per test session (the facade's defaults, 3000 starts, seed 0); read-only.
    """
    from ff_planner.model.profile import PlanRequest
    from ff_planner.optimize.planner import plan

    result = plan(PlanRequest(model="arm1dof", q0=[0.0], qf=[1.0], tf=1.0, uncertain=["pv", "pc", "pt"],
                              objective="robust-derivative", steps=5, starts=3000, seed=0))
    assert result.success and result.robust, result.message
    return result


# -- the test process's own resources, printed at the end of a run ----------------------------
# A suite whose ROS tests pass alone but fail late in a full run points at what earlier modules
# left behind in this process (threads, sockets) or at the machine (no real-time scheduling, few
# cores, load): the summary line says which, for the run that failed.
_RESOURCES: list[tuple[str, int, int]] = []    # (module, open fds, threads) after each module


def _open_fds() -> int:
    try:
        return len(os.listdir("/proc/self/fd"))
    except OSError:
        return -1


@pytest.fixture(scope="module", autouse=True)
def _record_resources(request):
    import threading

    yield
    _RESOURCES.append((request.module.__name__, _open_fds(), threading.active_count()))


def pytest_terminal_summary(terminalreporter, exitstatus, config) -> None:  # noqa: ARG001
    import resource
    import threading

    rt_ok: list[bool] = []

    def try_fifo() -> None:          # on a thread of its own, which then ends (Linux: per thread)
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
            rt_ok.append(True)
        except (AttributeError, OSError):
            rt_ok.append(False)

    th = threading.Thread(target=try_fifo)
    th.start()
    th.join()
    grew = sorted(((b[1] - a[1], b[2] - a[2], b[0]) for a, b in zip(_RESOURCES, _RESOURCES[1:])),
                  reverse=True)[:3]
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    terminalreporter.write_line(
        f"test process: {_open_fds()} open fds (limit {resource.getrlimit(resource.RLIMIT_NOFILE)[0]}), "
        f"{threading.active_count()} threads; SCHED_FIFO allowed: {'yes' if rt_ok and rt_ok[0] else 'no'}; "
        f"{os.cpu_count()} cpus, load {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}; most fds/threads left by: "
        + ", ".join(f"{m.rsplit('.', 1)[-1]} +{f}/+{t}" for f, t, m in grew))

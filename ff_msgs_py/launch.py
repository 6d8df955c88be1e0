"""Start and stop suite processes with safe ROS 2 network settings (no ROS launch on PyPI).

Every process the suite starts gets ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, a per-run
``ROS_DOMAIN_ID`` and a per-run ``ROS_LOG_DIR``, so nothing leaves loopback and parallel runs do
not see each other.
"""
from __future__ import annotations

import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Mapping, Optional, Sequence


def domain_in_use(domain_id: int) -> bool:
    """True if a DDS participant of ``domain_id`` lives on this machine.

    The first participant of a domain binds the RTPS metatraffic unicast port 7410 + 250·domain
    (Fast DDS / RTPS default port mapping), so a failing bind means the domain is taken.
    """
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind(("127.0.0.1", 7410 + 250 * int(domain_id)))
        return False
    except OSError:
        return True
    finally:
        sock.close()


def free_domain_id(exclude: frozenset[int] | set[int] = frozenset()) -> int:
    """A ROS_DOMAIN_ID in 1..100 that no process on this machine uses (random among the free ones)."""
    ids = [d for d in range(1, 101) if d not in exclude]
    random.shuffle(ids)
    for d in ids:
        if not domain_in_use(d):
            return d
    raise RuntimeError("every ROS_DOMAIN_ID in 1..100 is in use on this machine")


def ros_environment(domain_id: Optional[int] = None, log_dir: Optional[str] = None,
                    base: Optional[Mapping[str, str]] = None) -> dict[str, str]:
    """A copy of ``base`` (default os.environ) with loopback-only ROS settings.

    ``domain_id`` None picks a random id in 1..100 (Linux-safe range) that no other process on this
    machine uses; ``log_dir`` None makes a fresh temporary folder.
    """
    env = dict(os.environ if base is None else base)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["ROS_DOMAIN_ID"] = str(domain_id if domain_id is not None else free_domain_id())
    env["ROS_LOG_DIR"] = log_dir or tempfile.mkdtemp(prefix="ff-roslog-")
    env.pop("ROS_STATIC_PEERS", None)
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def client_ros_settings(domain_id: Optional[int] = None,
                        base: Optional[Mapping[str, str]] = None) -> tuple[int, dict[str, str]]:
    """(domain id, variables to set) for a tool that joins a running system, e.g. ``ff-ctl``.

    The domain: ``domain_id``, else ``ROS_DOMAIN_ID`` of ``base`` (default os.environ), else 0 (ROS's
    default). Discovery stays on loopback (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) unless
    ``base`` sets ``ROS_AUTOMATIC_DISCOVERY_RANGE`` itself. ValueError on a bad domain id.
    """
    env = os.environ if base is None else base
    raw = str(domain_id) if domain_id is not None else env.get("ROS_DOMAIN_ID", "").strip() or "0"
    try:
        dom = int(raw)
    except ValueError:
        raise ValueError(f"ROS_DOMAIN_ID must be a whole number, got {raw!r}") from None
    if not 0 <= dom <= 232:
        raise ValueError(f"ROS domain id must be 0..232, got {dom}")
    return dom, {"ROS_AUTOMATIC_DISCOVERY_RANGE": env.get("ROS_AUTOMATIC_DISCOVERY_RANGE") or "LOCALHOST",
                 "ROS_DOMAIN_ID": str(dom)}


def apply_ros_environment(env: Mapping[str, str]) -> None:
    """Put the ROS settings of ``env`` into this process (call before rclpy.init())."""
    for k in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_DOMAIN_ID", "ROS_LOG_DIR"):
        os.environ[k] = env[k]


@dataclass
class NodeProcess:
    """A child process running one node; output goes to ``log_path``."""

    name: str
    popen: subprocess.Popen
    log_path: Path
    _log: Optional[IO] = field(default=None, repr=False)

    @property
    def pid(self) -> int:
        return self.popen.pid

    def alive(self) -> bool:
        return self.popen.poll() is None

    def output(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return ""

    def stop(self, timeout: float = 5.0) -> int:
        """SIGINT, then SIGTERM, then SIGKILL, by PID; returns the exit code."""
        if self.popen.poll() is None:
            for sig, wait in ((signal.SIGINT, timeout), (signal.SIGTERM, 2.0), (signal.SIGKILL, 2.0)):
                try:
                    self.popen.send_signal(sig)
                except ProcessLookupError:
                    break
                try:
                    self.popen.wait(wait)
                    break
                except subprocess.TimeoutExpired:
                    continue
        if self._log is not None:
            self._log.close()
            self._log = None
        return self.popen.returncode if self.popen.returncode is not None else -9


def _default_sigint() -> None:
    """In the child before exec: SIGINT back to default. A non-interactive shell starts background
    jobs with SIGINT ignored, and an ignored signal survives exec: the node would then never see
    Ctrl-C / our stop() and only end on SIGTERM after a timeout."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start_module(name: str, module: str, args: Sequence[str], env: Mapping[str, str],
                 log_dir: Optional[str] = None) -> NodeProcess:
    """Run ``python -m module args`` as a child with ``env``; stdout+stderr to a log file."""
    folder = Path(log_dir or env.get("ROS_LOG_DIR") or tempfile.mkdtemp(prefix="ff-log-"))
    folder.mkdir(parents=True, exist_ok=True)
    log_path = folder / f"{name}.out"
    log = open(log_path, "w", buffering=1)
    popen = subprocess.Popen([sys.executable, "-u", "-m", module, *args], env=dict(env),
                             stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                             preexec_fn=_default_sigint)
    return NodeProcess(name, popen, log_path, log)


def wait_for_line(proc: NodeProcess, text: str, timeout: float = 20.0) -> bool:
    """Wait until ``text`` appears in the process output (True) or it dies / times out (False)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if text in proc.output():
            return True
        if not proc.alive():
            return text in proc.output()
        time.sleep(0.05)
    return False

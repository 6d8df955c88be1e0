"""The simulated rig (``python -m ff_hwbridge.cli.sim_rig``) as a child process, for benchmarks and
multi-process tests: start it hosting the loopback CAN hub, wait for ``sim rig ready``, send stdin
commands, stop it by its own PID. Plus the master configuration that matches the rig's default
drive (``sim.rig.RigConfig``'s first joint), so that the two sides' motor data are stated once.

No rclpy. All traffic stays on 127.0.0.1.
"""
from __future__ import annotations

import socket
import subprocess
import sys
import time
from typing import IO, Any, Mapping, Optional, Sequence

from ff_hwbridge.drive.config import BridgeConfig, load_config
from ff_hwbridge.sim.rig import RigConfig


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class RigError(RuntimeError):
    """The simulated rig process did not start or died; the message carries its output."""


class RigProcess:
    """``python -u -m ff_hwbridge.cli.sim_rig --host-hub PORT [args]`` with a stdin command channel.

    ``stderr``: a file for the rig's logs (kept apart from command replies); None merges them
    into stdout. ``prefix``: a command the rig runs under (e.g. ``["chrt", "-f", "10"]``).
    ``host_hub=False`` with ``bus_url`` joins an existing hub instead of hosting one.
    """

    def __init__(self, args: Sequence[str] = (), *, port: Optional[int] = None,
                 host_hub: bool = True, bus_url: Optional[str] = None,
                 env: Optional[Mapping[str, str]] = None, stderr: Optional[IO[Any]] = None,
                 prefix: Sequence[str] = (), ready_timeout: float = 30.0) -> None:
        self.port = port if port is not None else free_port()
        self.url = bus_url if bus_url is not None else f"ws://127.0.0.1:{self.port}/"
        where = ["--host-hub", str(self.port)] if host_hub else ["--bus-url", self.url]
        self.p = subprocess.Popen([*prefix, sys.executable, "-u", "-m", "ff_hwbridge.cli.sim_rig",
                                   *where, *args],
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  stderr=stderr if stderr is not None else subprocess.STDOUT,
                                  text=True, env=dict(env) if env is not None else None)
        self._stderr = stderr
        if not self._wait_ready(ready_timeout):
            out = self.kill()
            raise RigError(f"sim rig did not start within {ready_timeout} s: {out}")

    def _wait_ready(self, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            line = self._stdout.readline()
            if "sim rig ready" in line:
                return True
            if not line and self.p.poll() is not None:
                return False
        return False

    @property
    def _stdin(self) -> IO[str]:
        assert self.p.stdin is not None           # started with stdin=PIPE
        return self.p.stdin

    @property
    def _stdout(self) -> IO[str]:
        assert self.p.stdout is not None          # started with stdout=PIPE
        return self.p.stdout

    @property
    def pid(self) -> int:
        return self.p.pid

    def send(self, line: str) -> None:
        """Write one command without waiting for its reply."""
        self._stdin.write(line + "\n")
        self._stdin.flush()

    def cmd(self, line: str) -> str:
        """Write one command and return the rig's one-line reply."""
        self.send(line)
        return self._stdout.readline().strip()

    def stderr_text(self) -> str:
        """What the rig wrote to the ``stderr`` file so far ('' when merged into stdout)."""
        if self._stderr is None:
            return ""
        self._stderr.seek(0)
        return self._stderr.read()

    def stop(self, timeout: float = 10.0) -> int:
        """``quit`` (the rig writes its ``--record`` log), wait; kill if it does not exit."""
        try:
            self.send("quit")
            code = self.p.wait(timeout)
        except (OSError, ValueError, subprocess.TimeoutExpired):
            self.kill()
            code = self.p.wait(5)
        for pipe in (self.p.stdin, self.p.stdout):
            if pipe is not None and not pipe.closed:
                try:
                    pipe.close()
                except OSError:
                    pass
        return code

    def kill(self) -> str:
        """Kill this process (by its PID) if it still runs; return what is left on stdout."""
        if self.p.poll() is None:
            self.p.kill()
        try:
            out, _ = self.p.communicate(timeout=5)
        except (ValueError, OSError, subprocess.TimeoutExpired):
            out = ""
        return out or ""


def rig_master_data(url: str, family: str = "epos4", current_limit: float = 10.0,
                    node_id: int = 1, joint: Optional[Mapping[str, Any]] = None,
                    **settings: Any) -> dict[str, Any]:
    """The ``load_config`` data of ``rig_master_config`` (for a YAML file of ``ff-epos``)."""
    d = RigConfig(family=family).drive_configs()[0]
    return {
        **settings,
        "bus": {"interface": "remote", "channel": url},
        "joints": [{"name": "joint1", "node_id": node_id, "family": family,
                    "current_limit": current_limit,
                    "units": {"nominal_current": d.nominal_current,
                              "torque_constant": d.torque_constant,
                              "counts_per_rev": d.counts_per_rev, "gear_ratio": d.gear_ratio},
                    **(joint or {})}]}


def rig_master_config(url: str, family: str = "epos4", current_limit: float = 10.0,
                      node_id: int = 1, joint: Optional[Mapping[str, Any]] = None,
                      **settings: Any) -> BridgeConfig:
    """EposMaster settings for joint 1 of a rig started with its default model (motor data as the
    rig's drive serves them: nominal current A, kt Nm/A, counts per rev, gear ratio), over the hub
    at ``url``; ``joint`` adds keys to the joint (position_limits rad, ...), ``settings`` are
    further top-level keys of ``load_config`` (sync_period s, heartbeat_timeout s, ...)."""
    return load_config(rig_master_data(url, family, current_limit, node_id, joint, **settings))

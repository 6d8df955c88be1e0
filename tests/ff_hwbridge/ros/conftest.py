"""Fixtures of the bridge's ROS tests: the simulated rig in a process of its own."""
from __future__ import annotations

import re
import tempfile

import pytest


def _rig_state(rig) -> tuple[float, float, float]:
    """(q rad, qd rad/s, applied motor current A) of the rig's joint 1."""
    reply = rig.cmd("state")
    found = [re.search(rf"{k}=\[([^\],]*)", reply) for k in ("q", "qd", "i")]
    assert all(m is not None for m in found), reply
    q, qd, i = (float(m.group(1)) for m in found if m is not None)
    return q, qd, i


@pytest.fixture(scope="module")
def rig(ros_env):
    """A simulated rig (arm at 0 rad) for the module; ``rig.state()`` = (q, qd, current)."""
    from ff_hwbridge.sim.rig_process import RigProcess   # (the simulator: imported only when used)

    r = RigProcess(["--q0", "0.0"], env=ros_env, stderr=tempfile.TemporaryFile("w+"))
    r.state = lambda: _rig_state(r)
    yield r
    code = r.stop()
    assert code == 0, r.stderr_text()[-3000:]

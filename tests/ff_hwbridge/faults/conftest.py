"""A simulated rig started when the first test of this folder runs and left alone (its own hub,
nobody on it) until the stranger's test on an idle drive, the folder's last, uses it: the
two minutes of idling overlap the fault-injection tests; it stops with the folder's last test."""
from __future__ import annotations

import os
import time

import pytest

from tests.support.canopen_helpers import RigProcess


@pytest.fixture(scope="package", autouse=True)
def idle_rig(request):
    if not any(item.get_closest_marker("integration") for item in request.session.items
               if "faults" in str(item.fspath)):
        yield None
        return
    rig = RigProcess(["--model", "arm1dof", "--node-ids", "1"], stderr=open(os.devnull, "w"),
                     ready_timeout=120.0)
    try:
        yield rig, time.monotonic()
    finally:
        rig.stop()

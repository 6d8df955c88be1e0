"""The loopback CAN hub: binds 127.0.0.1 only, carries frames between OS processes, stops on
SIGTERM; remote buses opened on it get a working periodic sender."""
from __future__ import annotations

import re
import subprocess
import sys
import textwrap
import time

import can
import pytest

from ff_hwbridge.drive.bus import CanConfigError, open_bus
from ff_hwbridge.sim.can_hub import start_hub
from ff_msgs_py.launch import start_module, wait_for_line

ECHO = textwrap.dedent("""
    import sys, time, can
    from ff_hwbridge.drive.bus import open_bus
    bus = open_bus({"interface": "remote", "channel": sys.argv[1]})
    print("echo ready", flush=True)
    end = time.monotonic() + 20
    while time.monotonic() < end:
        m = bus.recv(0.2)
        if m is None:
            continue
        if m.arbitration_id == 0x123:
            bus.send(can.Message(arbitration_id=0x124, data=m.data, is_extended_id=False))
        elif m.arbitration_id == 0x7FF:
            break
    bus.shutdown()
""")


def hub_url(proc, timeout=20.0) -> str:
    assert wait_for_line(proc, "CAN hub on ws://", timeout), proc.output()
    return re.search(r"ws://[0-9.]+:\d+/", proc.output()).group(0)


def test_hub_binds_loopback_only():
    with start_hub(0) as hub:
        host, port = hub.bound_address()
        assert host == "127.0.0.1" and port == hub.port
        assert hub.url == f"ws://127.0.0.1:{port}/"
    for bad in ("0.0.0.0", "192.168.1.10", "example.com"):
        with pytest.raises(CanConfigError, match="loopback"):
            start_hub(0, host=bad)


@pytest.mark.integration
def test_frames_between_processes_and_clean_stop(ros_env):
    hub = start_module("can_hub", "ff_hwbridge.cli.can_hub", ["--port", "0"], ros_env)
    echo = None
    try:
        url = hub_url(hub)
        echo = subprocess.Popen([sys.executable, "-c", ECHO, url], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True, env=ros_env)
        assert echo.stdout.readline().strip() == "echo ready"
        bus = open_bus({"interface": "remote", "channel": url})
        try:
            got = []
            for i in range(50):
                bus.send(can.Message(arbitration_id=0x123, data=i.to_bytes(2, "little"),
                                     is_extended_id=False))
                end = time.monotonic() + 2.0
                while time.monotonic() < end:
                    m = bus.recv(0.5)
                    if m is not None and m.arbitration_id == 0x124:
                        got.append(int.from_bytes(m.data, "little"))
                        break
            assert got == list(range(50))
            bus.send(can.Message(arbitration_id=0x7FF, data=b"", is_extended_id=False))
        finally:
            bus.shutdown()
        assert echo.wait(10) == 0
        assert hub.alive()
    finally:
        if echo is not None and echo.poll() is None:
            echo.kill()
        code = hub.stop()
    assert code == 0 and "CAN hub stopped" in hub.output()


def test_periodic_sender_workaround_on_remote_bus():
    """canopen changes periodic frames (heartbeat state, SYNC); python-can-remote's own cyclic
    task breaks on that, the generic one installed by open_bus works."""
    with start_hub(0) as hub:
        tx, rx = open_bus(hub.bus_config()), open_bus(hub.bus_config())
        try:
            task = tx.send_periodic(can.Message(arbitration_id=0x705, data=b"\x7f",
                                                is_extended_id=False), 0.005)
            time.sleep(0.05)
            task.modify_data(can.Message(arbitration_id=0x705, data=b"\x05", is_extended_id=False))
            seen = set()
            end = time.monotonic() + 2.0
            while time.monotonic() < end and b"\x05" not in seen:
                m = rx.recv(0.2)
                if m is not None:
                    seen.add(bytes(m.data))
            task.stop()
            assert {b"\x7f", b"\x05"} <= seen
        finally:
            tx.shutdown()
            rx.shutdown()

"""Shared set-up for the ff_hwbridge tests: waiting on a condition, unique python-can virtual
channels, canopen Networks that close quickly, free loopback ports, the simulated rig process."""
from __future__ import annotations

import time
import uuid
from typing import Any, Callable, Optional

import canopen

from ff_hwbridge.drive.config import BridgeConfig, load_config
from ff_hwbridge.sim.rig_process import RigProcess, free_port  # noqa: F401  (re-exported for tests)


def waiter(default_timeout: float = 2.0, interval: float = 0.002) -> Callable[..., bool]:
    """``wait(pred, timeout=default_timeout)``: poll ``pred`` every ``interval`` s until it is
    true (-> True) or ``timeout`` s have passed (-> its last value)."""

    def wait(pred: Callable[[], object], timeout: float = default_timeout) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if pred():
                return True
            time.sleep(interval)
        return bool(pred())

    return wait


wait_for = waiter()


def unique_channel(prefix: str = "ff-test") -> str:
    """A python-can virtual channel name no other test uses."""
    return f"{prefix}-{uuid.uuid4().hex[:8]}"


def open_network(channel: str, interface: str = "virtual", notifier_cycle: float = 0.01,
                 bus=None) -> canopen.Network:
    """A connected canopen Network on ``channel`` (or on ``bus``) whose disconnect is quick."""
    net = canopen.Network(bus)
    net.NOTIFIER_CYCLE = notifier_cycle
    if bus is None:
        net.connect(interface=interface, channel=channel)
    else:
        net.connect()
    return net


def mini_config(channel: str, family: str = "epos4", n: int = 1, joint: Optional[dict] = None,
                **over: Any) -> BridgeConfig:
    """Master settings for ``n`` joints (node ids 1..n) of ``tests.support.mini_drive.MiniEpos``
    drives on the virtual ``channel``: 10 A limit, 3 A nominal current, 5 ms SYNC, 10 ms
    heartbeat, 0.3 s heartbeat timeout, 0.1 s setpoint watchdog; ``joint`` adds keys to every
    joint, ``over`` replaces top-level keys."""
    joints = [{"name": f"joint{i + 1}", "node_id": i + 1, "family": family, "current_limit": 10.0,
               "units": {"nominal_current": 3.0, "torque_constant": 0.0267, "counts_per_rev": 2048,
                         "gear_ratio": 54}, **(joint or {})} for i in range(n)]
    data: dict[str, Any] = {"bus": {"interface": "virtual", "channel": channel}, "joints": joints,
                            "sync_period": 0.005, "heartbeat_producer_ms": 10,
                            "heartbeat_timeout": 0.3, "setpoint_timeout": 0.1,
                            "boot_timeout": 2.0, "sdo_timeout": 2.0}
    data.update(over)
    return load_config(data)


def configure_and_enable(master, timeout: float = 2.0) -> None:
    """SDO/PDO set-up, NMT start and the enable sequence of an ``EposMaster``; asserts that every
    drive reaches OPERATION ENABLED within ``timeout`` s."""
    from ff_hwbridge.protocol.cia402 import State

    master.configure()
    master.enable()
    assert master.wait_for_state(State.OPERATION_ENABLED, timeout), master.fault_reason

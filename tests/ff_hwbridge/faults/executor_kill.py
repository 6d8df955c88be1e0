"""The executor process killed (SIGKILL, by its PID) in the middle of a motion on the simulated
ROS stack (``ff_executor.bringup.stack.Stack``, used as a library): the bridge's setpoint watchdog
must put the drive in the safe state. Timed at the simulated drive: a passive listener on the
stack's CAN hub records the drive's TxPDO1 (statusword, every SYNC) with the hub's bus
timestamps; the drive's first statusword outside OPERATION ENABLED after the kill is its own
report of the stop (resolution: one SYNC period). The reason is the bridge's ``/diagnostics``.

Used by ``test_executor_kill.py`` and ``benchmarks/bench_bridge_faults.py``."""
from __future__ import annotations

import os
import signal
import struct
import tempfile
import threading
import time
from typing import Any, Optional

import can

from ff_executor.bringup.stack import Stack, StackOptions
from ff_executor.ros.client import StackClient
from ff_msgs_py.convert import profile_to_msg
from ff_planner.model.profile import CurrentProfile

SW_MASK, SW_ENABLED = 0x6F, 0x27
MOVE_A = 0.8                  # A for 1 s, then -0.8 A for 1 s: the arm is moving at the kill
#: s after the bridge's watchdog runs out: its monitor, its quick stop and one 10 ms SYNC until
#: the drive reports it
REACTION_S = 0.2


def stop_bound(stack: Stack) -> float:
    """s from the kill to the drive leaving OPERATION ENABLED, at most: the bridge plays the
    setpoints already sent, stamped at most the executor's ``lead_time`` after the kill; its
    watchdog (``setpoint_timeout``; the executor repeats the present current more often) runs out
    at most that long after the last of them; then ``REACTION_S``. Read from the stack's own
    configuration, so the bound follows the config files."""
    cfg = stack.effective_config()
    lead = float(cfg["ff_executor"]["parameters"]["lead_time"])
    timeout = float(cfg["ff_hwbridge"]["config"]["setpoint_timeout"])
    return lead + timeout + REACTION_S


class _HubListener(can.Listener):
    """Statusword (0x181) and current (0x281, mA) frames of node 1 with their bus timestamps."""

    def __init__(self) -> None:
        self.status: list[tuple[float, int]] = []
        self.current: list[tuple[float, int]] = []

    def on_message_received(self, msg: can.Message) -> None:
        if msg.arbitration_id == 0x181 and len(msg.data) >= 2:
            self.status.append((msg.timestamp, struct.unpack_from("<H", msg.data)[0]))
        elif msg.arbitration_id == 0x281 and len(msg.data) >= 8:
            self.current.append((msg.timestamp, struct.unpack_from("<i", msg.data, 4)[0]))


def run(run_dir: Optional[str] = None, kill_after: float = 0.6) -> dict[str, Any]:
    """Start the stack (no planner), execute a 2 s profile, SIGKILL the executor ``kill_after`` s
    into it; returns the stop time at the drive (s after the kill), the bridge's reason, etc."""
    from diagnostic_msgs.msg import DiagnosticArray

    stack = Stack(StackOptions(planner=False, run_dir=run_dir or tempfile.mkdtemp(prefix="ff-exkill-")),
                  log=lambda _s: None)
    stack.start()
    client = StackClient(stack.env, "ff_fault_test")
    bus = can.Bus(interface="remote", channel=stack.hub_url, bitrate=1_000_000)
    listener = _HubListener()
    notifier = can.Notifier(bus, [listener], timeout=0.1)
    diag: list[str] = []
    client.node.create_subscription(
        DiagnosticArray, "/diagnostics",
        lambda m: diag.extend(f"{s.name}: {s.message}" for s in m.status if "hwbridge" in s.name), 50)
    try:
        client.reset_arm([0.0])
        profile = CurrentProfile([0.0, 1.0, 2.0], [[MOVE_A], [-MOVE_A]], tf=2.5, coast=0.5)
        msg = profile_to_msg(profile, "arm1dof", [0.0], [0.0])
        result: dict[str, Any] = {}

        def execute() -> None:
            try:
                result["outcome"] = client.execute(msg, timeout=6.0)
            except Exception as exc:  # noqa: BLE001 - the executor is killed: no result comes
                result["error"] = str(exc)

        mover = threading.Thread(target=execute, daemon=True)
        mover.start()
        end = time.monotonic() + 20.0
        while time.monotonic() < end and not any(abs(ma) >= 700 for _, ma in listener.current[-5:]):
            time.sleep(0.01)
        moving = any(abs(ma) >= 700 for _, ma in listener.current[-5:])
        time.sleep(kill_after)
        executor = next(p for p in stack.procs if p.name == "ff_executor")
        t_kill = time.time()
        os.kill(executor.pid, signal.SIGKILL)
        end = time.monotonic() + 5.0
        stop_t: Optional[float] = None
        while time.monotonic() < end and stop_t is None:
            stop_t = next((t for t, sw in list(listener.status)
                           if t > t_kill and sw & SW_MASK != SW_ENABLED), None)
            time.sleep(0.01)
        zero_t: Optional[float] = None
        end = time.monotonic() + 3.0
        while time.monotonic() < end and zero_t is None:
            zero_t = next((t for t, ma in list(listener.current) if t > t_kill and ma == 0), None)
            time.sleep(0.01)
        end = time.monotonic() + 3.0
        while time.monotonic() < end and not any("watchdog" in d or "safe" in d for d in diag):
            time.sleep(0.05)
        reason = next((d for d in reversed(diag) if "watchdog" in d or "safe" in d), diag[-1] if diag else "")
        last_sw = listener.status[-1][1] if listener.status else None
        return {"moving_at_kill": moving, "stop_bound_s": stop_bound(stack),
                "out_of_enabled_s": None if stop_t is None else stop_t - t_kill,
                "zero_current_s": None if zero_t is None else zero_t - t_kill,
                "statusword_after": None if last_sw is None else f"0x{last_sw:04X}",
                "reason": reason, "bridge_alive": all(p.alive() for p in stack.procs
                                                      if p.name != "ff_executor")}
    finally:
        notifier.stop()
        bus.shutdown()
        client.close()
        stack.stop()

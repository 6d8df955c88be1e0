"""Fault injection across processes: the simulated EPOS4 + arm in its own process (``RigProcess``,
CAN hub on 127.0.0.1), the suite's master (``EposMaster``, or an ``ff-epos`` process) on the same
hub, one fault at a time. Each scenario returns an :class:`Outcome`: whether the drive left
OPERATION ENABLED, how long after the injection by the DRIVE's own stamps (the simulated drive
stamps its state changes and its current's drop to 0 A on ``time.monotonic``, which is
system-wide on Linux; the injection instant is taken just before the command or signal, so the
figures include the pipe to the rig: upper bounds), and what the user reads (the master's
fault reason, warning or error message, the drive's state and error code).

``frozen_master``: the master frozen (SIGSTOP) or killed while SYNC (the hub's) and its heartbeat
(``HeartbeatKeeper``, standing for the kernel's broadcast manager on SocketCAN) go on; only the
simulated EPOS4's interpolation supervision (0x60C2, EMCY 0x8250) can stop the drive then.

Used by ``tests/ff_hwbridge/faults`` and ``benchmarks/bench_bridge_faults.py``. No rclpy.
"""
from __future__ import annotations

import json
import logging
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Optional

import can

from ff_hwbridge.drive.epos import EposError, EposMaster
from ff_hwbridge.drive.scheduler import use_fifo
from ff_hwbridge.protocol.cia402 import State
from ff_hwbridge.sim.rig_process import RigProcess, free_port, rig_master_config, rig_master_data

log = logging.getLogger(__name__)

__all__ = ["HARDWARE_TIMING", "Outcome", "SCENARIOS", "HeartbeatKeeper", "drive_info", "frozen_master",
           "run"]

#: Master settings of these scenarios: the hardware example's drive-side watchdogs (master
#: heartbeat 100 ms, consumed with 300 ms), 10 ms SYNC from the master, and master-side timeouts
#: that a loaded shared machine does not trip by itself.
HARDWARE_TIMING: dict[str, Any] = {
    "sync_period": 0.01, "heartbeat_producer_ms": 50, "heartbeat_timeout": 1.0,
    "setpoint_timeout": 30.0, "sdo_timeout": 2.0, "master_heartbeat_ms": 100,
    "master_heartbeat_timeout_ms": 300, "rpdo_timeout_ms": 0, "boot_wait": 15.0}
#: The scenarios that do not time the master's heartbeat give the drive 1 s of patience with it,
#: so that a loaded machine (the heartbeat crosses the hub process) does not trip it by itself.
PATIENT: dict[str, Any] = {**HARDWARE_TIMING, "master_heartbeat_timeout_ms": 1000}
HOLD_A = 0.5                 # A, the current held when the fault comes
START_TIMEOUT = 120.0        # s for a process to start (a loaded machine imports slowly)
#: SCHED_FIFO priority of what the scenarios time: the rig's threads (its reactions: bus lost,
#: master silent), the hub that stands for the bus, and the injection itself. A loaded machine
#: stalls normal-priority processes for up to ~1.4 s.
RT_PRIORITY = 20
RIG_ARGS = ["--model", "arm1dof", "--node-ids", "1", "--rt-priority", str(RT_PRIORITY)]


@dataclass
class Outcome:
    """What one injected fault did. Times in s after the injection (None: did not happen)."""

    fault: str
    must_stop: bool
    stopped: bool                        # the drive left OPERATION ENABLED (or never entered it)
    out_of_enabled_s: Optional[float]    # drive's stamp of leaving OPERATION ENABLED
    zero_current_s: Optional[float]      # drive's stamp of its current reaching 0 A
    drive_state: str
    drive_fault: str                     # 0x603F as the drive reports it
    reason: str                          # what the user reads
    notes: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


_SEEN = re.compile(r"seen at monotonic ([0-9.]+) s")
_FIELD = re.compile(r"(\w+)=('[^']*'|\{[^}]*\}|\[[^\]]*\]|\S+)")


def drive_info(rig: RigProcess, node: int = 1) -> dict[str, str]:
    """The rig's ``info NODE`` reply as fields (state, fault, i, left_enabled_t, zero_current_t,
    nmt, ...: strings, quotes removed)."""
    reply = rig.cmd(f"info {node}")
    if not reply.startswith("info"):
        raise RuntimeError(f"unexpected rig reply: {reply!r}")
    return {k: v.strip("'") for k, v in _FIELD.findall(reply)}


def _wait(pred: Callable[[], bool], timeout: float, period: float = 0.01) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(period)
    return bool(pred())


def _outcome(fault: str, must_stop: bool, rig: RigProcess, t0: float, reason: str,
             wait: float = 3.0, **notes: Any) -> Outcome:
    """Poll the drive until it left OPERATION ENABLED (``must_stop``) or for 0.5 s, then read
    its stamps relative to ``t0`` (monotonic s)."""
    if must_stop:
        _wait(lambda: drive_info(rig)["state"] != State.OPERATION_ENABLED.value, wait)
        _wait(lambda: float(drive_info(rig)["i"]) == 0.0, wait)
    else:
        time.sleep(0.5)
    info = drive_info(rig)
    left, zero = float(info["left_enabled_t"]), float(info["zero_current_t"])
    return Outcome(fault, must_stop, info["state"] != State.OPERATION_ENABLED.value,
                   left - t0 if left >= t0 else None, zero - t0 if zero >= t0 else None,
                   info["state"], f"0x{info['fault']}" if not info["fault"].startswith("0x") else info["fault"],
                   reason, notes)


class _Bench:
    """A rig process and an EposMaster (this process) on the rig's hub."""

    def __init__(self, rig_args: tuple[str, ...] = (), joint: Optional[dict[str, Any]] = None,
                 bus_url: Optional[str] = None, **settings: Any) -> None:
        self.log_file = tempfile.TemporaryFile("w+")
        self.rig = RigProcess([*RIG_ARGS, *rig_args], stderr=self.log_file,
                              host_hub=bus_url is None, bus_url=bus_url, ready_timeout=START_TIMEOUT)
        self.master = EposMaster(rig_master_config(self.rig.url, joint=joint,
                                                   **{**PATIENT, **settings}))

    def enable_and_hold(self, amps: float = HOLD_A) -> None:
        """Configure, enable and hold ``amps`` A; RuntimeError if the drive does not."""
        m = self.master
        m.connect()
        m.configure()
        m.enable()
        if not m.wait_for_state(State.OPERATION_ENABLED, 10.0):
            raise RuntimeError(f"drive not enabled: {m.states()} {m.fault_reason}")
        m.command_currents([amps])
        if not _wait(lambda: abs(float(drive_info(self.rig)["i"]) - amps) < 0.003, 5.0):
            raise RuntimeError(f"drive does not hold {amps} A: {drive_info(self.rig)}")
        time.sleep(0.3)                   # the drive has seen several master heartbeats

    def close(self) -> None:
        try:
            self.master.disconnect()
        except Exception:  # noqa: BLE001 - a master whose bus is gone cannot close it cleanly
            pass
        self.rig.stop()
        self.log_file.close()


def _inject(action: Callable[[], None]) -> float:
    """Run ``action`` (a kill, a signal) from this thread under SCHED_FIFO ``RT_PRIORITY`` and
    return ``time.monotonic()`` just before it: a normal-priority caller preempted between its
    stamp and the kill would add the stall to the drive's reaction time. The thread's scheduling
    policy is restored afterwards."""
    policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    raised = use_fifo(RT_PRIORITY, "fault injection")
    try:
        t0 = time.monotonic()
        action()
        return t0
    finally:
        if raised:
            os.sched_setscheduler(0, policy, param)


def _master_latch(m: EposMaster, timeout: float = 3.0) -> str:
    _wait(lambda: m.latched, timeout)
    return m.fault_reason or ""


def _holding_epos(config_path: str) -> subprocess.Popen:
    """An ``ff-epos`` process that enables the drive and holds ``HOLD_A`` for up to 60 s."""
    return subprocess.Popen([sys.executable, "-u", "-m", "ff_hwbridge.cli.epos", "--config",
                             config_path, "--enable", "--current", str(HOLD_A), "--hold", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)


def _await_hold(p: subprocess.Popen, rig: RigProcess) -> None:
    """Until ``p`` says it enabled the drive and the rig's drive holds ``HOLD_A``; RuntimeError if
    it does not within 5 s after that."""
    assert p.stdout is not None
    end = time.monotonic() + START_TIMEOUT
    while time.monotonic() < end:
        line = p.stdout.readline()
        if '"enabled": true' in line or (not line and p.poll() is not None):
            break
    if not _wait(lambda: abs(float(drive_info(rig)["i"]) - HOLD_A) < 0.003, 5.0):
        raise RuntimeError(f"ff-epos did not make the drive hold {HOLD_A} A: {drive_info(rig)}")


# --- scenarios -----------------------------------------------------------------------------------
def master_signal(sig: int) -> Outcome:
    """An ``ff-epos`` process holding 0.5 A gets ``sig`` (SIGKILL: dead; SIGSTOP: hung, its
    heartbeat thread frozen too): the drive's heartbeat consumer must stop it."""
    name = {int(signal.SIGKILL): "master_sigkill", int(signal.SIGSTOP): "master_sigstop"}[int(sig)]
    log_file = tempfile.TemporaryFile("w+")
    rig = RigProcess(RIG_ARGS, stderr=log_file, ready_timeout=START_TIMEOUT)
    with tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False) as fh:
        json.dump(rig_master_data(rig.url, **HARDWARE_TIMING), fh)     # JSON is YAML
    p = _holding_epos(fh.name)
    try:
        _await_hold(p, rig)
        time.sleep(0.3)
        before = drive_info(rig)["state"]
        t0 = _inject(lambda: os.kill(p.pid, sig))
        out = _outcome(name, True, rig, t0, "")
        out.reason = f"drive: {out.drive_state}, 0x603F {out.drive_fault}"
        if before != State.OPERATION_ENABLED.value:
            out.notes["tripped_before_the_signal"] = before    # e.g. a starved heartbeat
        return out
    finally:
        if sig == signal.SIGSTOP and p.poll() is None:
            os.kill(p.pid, signal.SIGCONT)
        p.kill()
        p.wait(5)
        rig.stop()
        log_file.close()
        os.unlink(fh.name)


class HeartbeatKeeper:
    """What the kernel's broadcast manager does on SocketCAN for a process that handed it a
    periodic frame and then froze: the master's heartbeat (0x700 + ``node_id``, NMT state
    OPERATIONAL) goes on from another process (this one), every ``period`` s, over its own
    connection to the hub at ``url``; its thread under SCHED_FIFO ``RT_PRIORITY`` where allowed."""

    def __init__(self, url: str, node_id: int, period: float) -> None:
        self._bus = can.Bus(interface="remote", channel=url)
        self._msg = can.Message(arbitration_id=0x700 + node_id, data=[0x05], is_extended_id=False)
        self._period = period
        self._stop = threading.Event()
        self.sent = 0
        self._thread = threading.Thread(target=self._run, name="heartbeat-keeper", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        use_fifo(RT_PRIORITY, "heartbeat keeper")
        nxt = time.monotonic()
        while not self._stop.is_set():
            self._bus.send(self._msg)
            self.sent += 1
            nxt += self._period
            self._stop.wait(max(0.0, nxt - time.monotonic()))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._bus.shutdown()


#: s, SYNC period of the frozen-master scenario (the hub's, from outside the master)
FROZEN_SYNC_S = 0.01


def frozen_master(sig: int, supervision: bool = True, watch_s: float = 1.0) -> Outcome:
    """An ``ff-epos`` process holds 0.5 A in CST; SYNC comes from the hub (10 ms, another
    process), the master's RxPDO1 goes out in every SYNC cycle and 0x60C2 = the SYNC period. It
    gets ``sig`` (SIGSTOP: frozen; SIGKILL: dead) while this process keeps its heartbeat going,
    as the kernel's broadcast manager does on SocketCAN: neither SYNC nor the heartbeat stops,
    so only the drive's interpolation supervision (EMCY 0x8250) can stop the drive.
    ``supervision=False`` is the control: that supervision off in the drive (the rig's
    ``supervision 1 off``), the drive is watched for ``watch_s`` s and must NOT have stopped."""
    name = {int(signal.SIGKILL): "master_frozen_sigkill",
            int(signal.SIGSTOP): "master_frozen_sigstop"}[int(sig)]
    log_file = tempfile.TemporaryFile("w+")
    rig = RigProcess([*RIG_ARGS, "--sync-period", str(FROZEN_SYNC_S)], stderr=log_file,
                     ready_timeout=START_TIMEOUT)
    timing = {**HARDWARE_TIMING, "sync_period": FROZEN_SYNC_S, "sync_producer": "external"}
    with tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False) as fh:
        json.dump(rig_master_data(rig.url, **timing), fh)              # JSON is YAML
    p = _holding_epos(fh.name)
    keeper: Optional[HeartbeatKeeper] = None
    try:
        _await_hold(p, rig)
        keeper = HeartbeatKeeper(rig.url, int(timing.get("master_node_id", 127)),
                                 timing["master_heartbeat_ms"] / 1000.0)
        if not supervision:
            name += "_supervision_off"
            rig.cmd("supervision 1 off")
        time.sleep(0.3)
        before = drive_info(rig)
        t0 = _inject(lambda: os.kill(p.pid, sig))
        if supervision:
            out = _outcome(name, True, rig, t0, "")
        else:
            time.sleep(watch_s)
            out = _outcome(name, False, rig, t0, "")
        out.reason = f"drive: {out.drive_state}, 0x603F {out.drive_fault}"
        after = drive_info(rig)
        syncs_before = int(before["last_sync_ns"])
        out.notes.update(
            heartbeats_kept=keeper.sent, hb_age_after=after["hb_age"],
            sync_went_on=int(after["last_sync_ns"]) > syncs_before,
            supervision=before.get("supervision"), current_a_after=float(after["i"]))
        if before["state"] != State.OPERATION_ENABLED.value:
            out.notes["tripped_before_the_signal"] = f"{before['state']}, {before['fault']}"
        return out
    finally:
        if keeper is not None:
            keeper.close()
        if sig == signal.SIGSTOP and p.poll() is None:
            os.kill(p.pid, signal.SIGCONT)
        p.kill()
        p.wait(5)
        rig.stop()
        log_file.close()
        os.unlink(fh.name)


def emcy_error() -> Outcome:
    """The drive raises an error (0x2310 over current): it faults by itself; the master latches."""
    b = _Bench()
    try:
        b.enable_and_hold()
        t0 = time.monotonic()
        b.rig.send("emcy 1 0x2310")
        b.rig._stdout.readline()
        reason = _master_latch(b.master)
        _wait(lambda: bool(b.master.status()["joint1.error_history"]), 3.0)
        return _outcome("emcy_error", True, b.rig, t0, reason,
                        error_history=b.master.status()["joint1.error_history"])
    finally:
        b.close()


def emcy_warning() -> Outcome:
    """The drive warns (0xFF01): it keeps driving; the master shows the warning, no latch."""
    b = _Bench()
    try:
        b.enable_and_hold()
        t0 = time.monotonic()
        b.rig.cmd("warn 1 0xFF01")
        _wait(lambda: bool(b.master.status()["joint1.last_warning"]), 3.0)
        out = _outcome("emcy_warning", False, b.rig, t0, b.master.status()["joint1.last_warning"])
        out.notes.update(latched=b.master.latched, current_a=float(drive_info(b.rig)["i"]),
                         statusword_warning=b.master.status()["joint1.warning"])
        return out
    finally:
        b.close()


def estop() -> Outcome:
    """The e-stop (``EposMaster.estop``, behind the bridge's ~/estop service and topic)."""
    b = _Bench()
    try:
        b.enable_and_hold()
        t0 = time.monotonic()
        reason = b.master.estop("test")
        return _outcome("estop", True, b.rig, t0, reason)
    finally:
        b.close()


def envelope_breach(limit: float = 0.1, amps: float = 1.0) -> Outcome:
    """The arm driven out of its position envelope [-limit, limit] rad: the master latches at
    the first position outside; times from that latch."""
    b = _Bench(joint={"position_limits": [-limit, limit]})
    try:
        b.enable_and_hold(0.0)
        b.master.command_currents([amps])
        _wait(lambda: b.master.latched, 10.0)
        latches = [t for t, text in b.master.events if text.startswith("safe state")]
        t0 = latches[-1] if latches else time.monotonic()
        out = _outcome("envelope_breach", True, b.rig, t0, b.master.fault_reason or "")
        out.notes["limit_rad"] = limit
        return out
    finally:
        b.close()


def fault_at_start() -> Outcome:
    """The drive is in Fault (0x2310) before the master connects: configure goes through, the
    enable is refused by the drive (or by the master itself, when the drive's Fault statusword
    reached it first and latched the safe state), the master latches and shows the drive's
    error code."""
    b = _Bench()
    try:
        b.rig.cmd("emcy 1 0x2310")
        t0 = time.monotonic()
        b.master.connect()
        b.master.configure()
        try:
            b.master.enable()
        except EposError as exc:
            if not b.master.latched:
                raise
            log.info("enable refused by the latched master: %s", exc)
        reason = _master_latch(b.master, 5.0)
        _wait(lambda: bool(b.master.status()["joint1.error_history"]), 3.0)
        out = _outcome("fault_at_start", True, b.rig, t0, reason)
        out.notes["error_history"] = b.master.status()["joint1.error_history"]
        return out
    finally:
        b.close()


def scaling_mismatch() -> Outcome:
    """The drive is set up for 2.5 A nominal current, the config says 3 A: configure refused."""
    b = _Bench(rig_args=("--nominal-current", "2.5"))
    try:
        t0 = time.monotonic()
        b.master.connect()
        try:
            b.master.configure()
            reason = "configure accepted the disagreeing motor data"
        except EposError as exc:
            reason = str(exc)
        return _outcome("scaling_mismatch", False, b.rig, t0, reason)
    finally:
        b.close()


class _Records(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


def powered_late(delay: float = 5.0) -> Outcome:
    """The drive is powered ``delay`` s after the master starts configuring: the master waits
    (NMT reset communication every boot_timeout s, a log line each time) and configures it."""
    b = _Bench(rig_args=("--boot-delay", str(delay)))
    records = _Records()
    logging.getLogger("ff_hwbridge.drive.epos").addHandler(records)
    try:
        t0 = time.monotonic()
        b.master.connect()
        try:
            b.master.configure()
            configured = time.monotonic() - t0
            b.master.enable()
            enabled = b.master.wait_for_state(State.OPERATION_ENABLED, 5.0)
        except EposError as exc:
            configured, enabled = None, False
            records.lines.append(str(exc))
        out = _outcome("powered_late", False, b.rig, t0, "; ".join(records.lines[:1] + records.lines[-1:]))
        out.notes.update(configured_after_s=configured, enabled=enabled, delay_s=delay,
                         log_lines=len(records.lines))
        return out
    finally:
        logging.getLogger("ff_hwbridge.drive.epos").removeHandler(records)
        b.close()


def hub_restart(down_s: float = 1.0) -> Outcome:
    """The CAN hub process (``ff-can-hub``) is killed and started again on the same port after
    ``down_s`` s. The simulated drive takes the lost hub as bus off (Fault 0x81FD, current 0),
    reconnects and reports it; the master loses its bus too and latches on the drive's silence.
    The hub runs under SCHED_FIFO: killed, it is gone at once, as a bus fails, whatever else
    holds the CPU."""
    port = free_port()
    hub_cmd = [sys.executable, "-u", "-m", "ff_hwbridge.cli.can_hub", "--port", str(port),
               "--rt-priority", str(RT_PRIORITY)]

    def start_hub() -> subprocess.Popen:
        hub = subprocess.Popen(hub_cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        assert hub.stdout is not None
        if "CAN hub on" not in hub.stdout.readline():      # blocks until it serves (or dies)
            hub.kill()
            raise RuntimeError("ff-can-hub did not start")
        return hub

    hub = start_hub()
    b = None
    try:
        b = _Bench(bus_url=f"ws://127.0.0.1:{port}/")
        b.enable_and_hold()
        t0 = _inject(hub.kill)
        hub.wait(5)
        hub_reaped = time.monotonic() - t0
        out = _outcome("hub_restart", True, b.rig, t0, "")
        time.sleep(down_s)
        hub = start_hub()
        back = _wait(lambda: drive_info(b.rig)["nmt"] == "PRE-OPERATIONAL", 10.0)
        out.reason = _master_latch(b.master)
        rig_log = [ln[ln.index("ff-sim-rig:"):] for ln in b.rig.stderr_text().splitlines()
                   if "ff-sim-rig:" in ln]
        seen = next((float(m.group(1)) for m in map(_SEEN.search, rig_log) if m), None)
        # where the time went: the hub reaped by this process (an upper bound of its exit), the
        # rig's bus watch seeing python-can's receive error (its own CLOCK_MONOTONIC, system-wide)
        out.notes.update(drive_back_on_bus=back, nmt_after=drive_info(b.rig)["nmt"],
                         fault_after=drive_info(b.rig)["fault"], rig_log=rig_log,
                         hub_reaped_s=hub_reaped, bus_loss_seen_s=None if seen is None else seen - t0)
        return out
    finally:
        if b is not None:
            b.close()
        hub.kill()
        hub.wait(5)


#: name -> scenario; every one starts and stops its own processes
SCENARIOS: dict[str, Callable[[], Outcome]] = {
    "master_sigkill": lambda: master_signal(signal.SIGKILL),
    "master_sigstop": lambda: master_signal(signal.SIGSTOP),
    "master_frozen_sigstop": lambda: frozen_master(signal.SIGSTOP),
    "master_frozen_sigkill": lambda: frozen_master(signal.SIGKILL),
    "hub_restart": hub_restart,
    "powered_late": powered_late,
    "fault_at_start": fault_at_start,
    "scaling_mismatch": scaling_mismatch,
    "emcy_warning": emcy_warning,
    "emcy_error": emcy_error,
    "envelope_breach": envelope_breach,
    "estop": estop,
}


def run(name: str) -> Outcome:
    """Run one scenario of ``SCENARIOS`` by name."""
    return SCENARIOS[name]()

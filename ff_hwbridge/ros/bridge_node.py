"""ROS 2 lifecycle node ``ff_hwbridge``: stamped current setpoints -> EPOS drives over CANopen.

A thin adapter around :class:`ff_hwbridge.drive.epos.EposMaster` (protocol, state machine, safety) and
:class:`ff_hwbridge.drive.player.SetpointPlayer` (guard, units and RPDO of each setpoint at its
stamp): the subscription feeds the player, the node publishes what the player reports.

Lifecycle (rclpy.lifecycle):
- configure:  read the bridge config, open the bus, NMT/SDO/PDO set-up of every drive, SYNC,
              heartbeat/EMCY monitoring; create topics, service, timers. Failure -> ErrorProcessing.
- activate:   enable operation (CiA 402 transitions 2, 3, 4) with zero current; setpoints are
              accepted from now on. Failure (drive does not reach Operation enabled, safe state
              latched) -> ErrorProcessing.
- deactivate: drop pending setpoints, zero current, disable operation (transition 5).
- cleanup:    stop the scheduler, disable voltage, stop SYNC, close the bus, remove topics.
- shutdown:   as cleanup, from any state.
- error:      log the reason, close everything best effort, back to unconfigured.

Interfaces (relative to the node: /ff_hwbridge/...):
- sub ``~/setpoints``   ff_msgs/msg/CurrentSetpoint: applied at ``stamp`` (ROS system clock).
- pub ``~/joint_states`` sensor_msgs/JointState: position rad, velocity rad/s, effort = joint
  torque N·m (gear_ratio x kt x measured motor current, as ros2_control expects); stamped with
  the instant the drive sampled the position (the SYNC its TPDO1 answers, on the bus clock),
  published once per new sample.
- pub ``~/motor_currents`` sensor_msgs/JointState: the same samples with effort = measured motor
  current A (what the drive reports; what the executor compares with its setpoints).
- sub ``~/joint_commands`` (parameter ``command_topic``) sensor_msgs/JointState: effort commands
  in N·m at the joint, as ros2_control's ``joint_state_topic_hardware_interface`` publishes them
  for an ``effort`` command interface (``name`` + ``effort``, position/velocity empty). Each is
  converted to motor current (A = N·m / (gear_ratio x kt)) and applied at once through the same
  player and safety guard as the setpoints (clamp to the current limit; NaN effort, ros2_control's
  unset command, = 0 A). A non-zero command starts the setpoint watchdog: commands that stop for
  ``setpoint_timeout`` s latch the safe state (zero current + quick stop) until ``~/fault_reset``;
  zero effort on every joint ends the motion (no watchdog). Refused (logged once per cause) while
  a CurrentProfile runs; a profile's setpoints are refused while non-zero commands are live.
- pub ``~/applied``     ff_msgs/msg/CurrentSetpoint: each applied setpoint, stamp = when it was sent.
- pub ``/diagnostics``  diagnostic_msgs/DiagnosticArray: drive states, safe-state reason, timing.
- srv ``~/fault_reset`` std_srvs/Trigger: clear the safe state and reset drive faults (re-enables
  when active).
- srv ``~/estop``       std_srvs/Trigger: emergency stop: latch the safe state (zero current, quick
  stop) with the reason "e-stop: service ~/estop" until ``~/fault_reset``.
- sub ``~/emergency_stop`` std_msgs/Bool: the same from a topic (an e-stop button's node, a safety
  PLC bridge): ``true`` latches with the reason "e-stop: topic ~/emergency_stop"; ``false`` does
  nothing (clearing is ``~/fault_reset`` only).
- pub ``~/status``     ff_msgs/msg/DriveGroupStatus: the drive group typed (state, latch reason, a
  failed configure's reason, drive states, EMCY, owner, lease, refusals), beside ``/diagnostics``;
  published also while unconfigured (1 Hz).
- srv ``~/claim``      ff_msgs/srv/ClaimDrive: CLAIM (-> token), RENEW, RELEASE.
- srv ``~/owner_command`` ff_msgs/srv/OwnerCommand: the owner's FAULT_RESET and ENABLE (activate).

Ownership (:mod:`ff_hwbridge.ownership`). Setpoints, effort commands, fault resets and enables
move the arm only when they are the owner's: the client holding the claim (its token in
``CurrentSetpoint.token``, the effort command's ``header.frame_id``, ``OwnerCommand.token``), or,
while nobody holds a claim, the ``default_owner`` node (default ``ff_executor`` in the bridge's
namespace) for token-less setpoints / effort commands when it is the topic's only publisher.
While a claim is held, ``~/fault_reset`` and a lifecycle activate are refused (the owner uses
``~/owner_command``); without one they are open as before. A claim lasts ``claim_lease`` s past
the owner's latest renewal or accepted command; released or expired during a motion, the safe
state latches. Every refusal is logged (at most once a second per kind) and counted
(``owner.refused.*`` in ``/diagnostics``). The e-stop is open to everyone, always.

After configure the flat parameters show the configuration in use (also when it came from
``config_file``); while configured they cannot be changed (refused with the reason: cleanup,
set, configure again).

Parameters: ``config_file`` (bridge YAML, config/bridge_*.yaml) or the flat parameters below
(``--ros-args --params-file``); ``bus_interface``/``bus_channel`` override the bus (e.g. the
CAN hub's ws://127.0.0.1:PORT/). Command line: ``ff-hwbridge [--autostart] [--config PATH]
[--channel URL] [--ros-args ...]``.
"""
from __future__ import annotations

import argparse
import dataclasses
import gc
import json
import logging
import math
import sys
import threading
import time
from typing import Any, Callable, Optional, Sequence, Union

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.qos import qos_profile_sensor_data
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from rclpy.utilities import remove_ros_args
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from ff_hwbridge.drive.config import (OPTION_RANGES, BridgeConfig, BusConfig, ConfigError, config_from_mapping,
                                      load_config, with_bus)
from ff_hwbridge.drive.epos import EposError, EposMaster
from ff_hwbridge.drive.player import AppliedSetpoint, SetpointPlayer, SetpointRejected
from ff_hwbridge.drive.player_process import ProcessPlayer
from ff_hwbridge.drive.realtime import (SWITCH_INTERVAL, IdleCollector, RealtimeConfig, freeze_heap,
                                        hold_full_collections, setup_process)
from ff_hwbridge.drive.realtime import pauses as gc_pauses
from ff_hwbridge.ownership import ClaimRefused, Ownership, qualified_name
from ff_hwbridge.protocol.cia402 import State
from ff_hwbridge.protocol.units import DriveUnits
from ff_msgs.msg import CurrentSetpoint, DriveGroupStatus
from ff_msgs.srv import ClaimDrive, OwnerCommand
from ff_msgs_py.shutdown import shut_down
from ff_msgs_py.threads import in_thread
from ff_msgs_py.spin import spin

READY_LINE = "ff_hwbridge ready"
NODE_NAME = "ff_hwbridge"
#: s the executor runs with the drives configured before ``--autostart`` enables them
AUTOSTART_SETTLE_S = 0.5

#: BridgeConfig's own defaults (ff_hwbridge.drive.config): the flat parameters' defaults come from
#: them, never typed twice; an unset rpdo_timeout_ms (None) is -1 here (ROS has no None)
_CONFIG_DEFAULTS: dict[str, Any] = {f.name: f.default for f in dataclasses.fields(BridgeConfig)
                                    if f.default is not dataclasses.MISSING}
_UNITS = DriveUnits()
_BUS = BusConfig()


def _default(name: str) -> Any:
    """The default of BridgeConfig field ``name`` as a ROS parameter value."""
    value = _CONFIG_DEFAULTS[name]
    return -1 if value is None else value


# name: (default, description) — the flat form of config/bridge_*.yaml
PARAMS: dict[str, tuple[Any, str]] = {
    "config_file": ("", "bridge YAML; when set, the flat joint/bus parameters are ignored"),
    "bus_interface": ("", "python-can interface override (socketcan, pcan, kvaser, remote, virtual)"),
    "bus_channel": ("", "python-can channel override (e.g. can0, ws://127.0.0.1:54701/)"),
    "bus_bitrate": (_BUS.bitrate, "bit/s"),
    "joint_names": (["joint1"], "one per drive"),
    "node_ids": ([1], "CANopen node id per joint"),
    "families": ([_UNITS.family], "'epos4' (CST) or 'epos2' (current mode) per joint"),
    "current_limits": ([10.0], "A per joint; every command is clamped to it"),
    "nominal_currents": ([_UNITS.nominal_current], "A per joint (motor nominal current; EPOS4 per mille base)"),
    "torque_constants": ([_UNITS.torque_constant], "Nm/A per joint"),
    "counts_per_rev": ([_UNITS.counts_per_rev], "encoder increments per motor revolution, per joint"),
    "gear_ratios": ([_UNITS.gear_ratio], "per joint"),
    "sync_period": (_default("sync_period"), "s, SYNC period (10 ms supported from Python; 1 ms experimental)"),
    "heartbeat_producer_ms": (_default("heartbeat_producer_ms"), "ms, written to each drive's 0x1017"),
    "heartbeat_timeout": (_default("heartbeat_timeout"), "s, heartbeat consumer timeout -> safe state "
                               "(0 = 3 x heartbeat_producer_ms + timeout_margin)"),
    "timeout_margin": (_default("timeout_margin"),
        "s, scheduling margin of the derived heartbeat / SYNC / feedback timeouts"),
    "master_heartbeat_ms": (_default("master_heartbeat_ms"),
        "ms, > 0: produce a master heartbeat the drives consume (0x1016); 0 = off"),
    "master_heartbeat_timeout_ms": (_default("master_heartbeat_timeout_ms"), "ms, the drives' consumer time "
                                       "(0 = max(3 x master_heartbeat_ms, heartbeat_timeout))"),
    "master_node_id": (_default("master_node_id"), "node id of the master's heartbeat"),
    "rpdo_timeout_ms": (_default("rpdo_timeout_ms"),
        "ms, RxPDO1 event timer 0x1400:05 where a drive has it (nothing relies on it: "
                            "the drive's interpolation supervision stops a hung bridge); 0 = off, "
                            "-1 = max(500, 2 x heartbeat_timeout)"),
    "quick_stop_option": (_default("quick_stop_option"), "0x605A quick stop option code (maxon: 0, 1, 2, 5, 6)"),
    "fault_reaction_option": (_default("fault_reaction_option"),
        "0x605E fault reaction option code (0 disable drive, 1/2 ramp)"),
    "abort_connection_option": (_default("abort_connection_option"),
        "0x6007 on a communication error: 0 none, 1 fault, 2 disable voltage, 3 quick stop"),
    "communication_error_behaviour": (_default("communication_error_behaviour"),
        "0x1029:01: 0 pre-operational, 1 unchanged, 2 stopped"),
    "scaling_source": (_default("scaling_source"),
        "motor data: 'check' against the drive, 'drive' (use its), 'config' (write ours)"),
    "scaling_tolerance": (_default("scaling_tolerance"), "relative tolerance of the motor data check"),
    "setpoint_timing": (_default("setpoint_timing"),
        "'sync': setpoint RPDOs latched by the drives at SYNC (transmission "
                                "type 1, sent the cycle before); 'on_receipt': type 255"),
    "sync_producer": (_default("sync_producer"), "'master': this bridge produces SYNC; 'external': another node "
                                "(the simulation's CAN hub)"),
    "sync_timeout": (_default("sync_timeout"), "s, no SYNC this long -> safe state "
                          "(0 = max(3 x sync_period + timeout_margin, heartbeat_timeout))"),
    "missed_cycle_tolerance": (_default("missed_cycle_tolerance"),
        "SYNC cycles a setpoint may take effect late before the safe state"),
    "feedback_every": (_default("feedback_every"), "SYNCs per feedback TPDO (their transmission type 1..240)"),
    "boot_timeout": (_default("boot_timeout"), "s per NMT reset communication waiting for the boot-up frame"),
    "boot_wait": (_default("boot_wait"), "s in all waiting for a drive to boot (retries every boot_timeout)"),
    "check_identity": (_default("check_identity"), "0x1000 profile 402 and 0x1018:01 vendor maxon"),
    "position_limits": ([0.0], "rad, [low1, high1, low2, high2, ...] per joint; [0.0] or [] = none"),
    "velocity_limits": ([0.0], "rad/s per joint, 0 = none"),
    "setpoint_timeout": (_default("setpoint_timeout"), "s, no fresh setpoint during a motion -> safe state"),
    "feedback_timeout": (_default("feedback_timeout"), "s, no feedback TPDO this long -> safe state "
                         "(0 = derived from sync_period x feedback_every + timeout_margin)"),
    "sdo_timeout": (_default("sdo_timeout"), "s, answer time of one SDO transfer at configure"),
    "state_timeout": (_default("state_timeout"), "s, a CiA 402 state change (enable, fault reset) must "
                      "be reached within this"),
    "monitor_period": (_default("monitor_period"), "s, period of the master's supervision loop"),
    "reset_communication": (_default("reset_communication"), "NMT reset communication of each drive at "
                            "configure (then wait for its boot-up)"),
    "player_process": (_default("player_process"), "synchronous timing: the setpoint player in a process "
                       "of its own"),
    "setpoint_lead": (_default("setpoint_lead"), "s, no longer used (accepted with a warning): the player "
                      "sends every setpoint itself, in the cycle before its SYNC"),
    "stall_dump": (_default("stall_dump"), "s, the player away this long with setpoints pending dumps "
                   "every thread's stack to the log (0 = off)"),
    "spin_margin": (_default("spin_margin"), "s, the scheduler sleeps until this long before a stamp, then spins"),
    "scheduler_rt_priority": (_default("scheduler_rt_priority"),
        "1..99: SCHED_FIFO for the setpoint player and bus receiver "
                              "(needs CAP_SYS_NICE); 0 = off; -1 = auto (50 when synchronous)"),
    "command_topic": ("~/joint_commands", "sensor_msgs/JointState effort commands, N·m at the joint "
                      "(ros2_control joint_state_topic_hardware_interface); '' = none"),
    "default_owner": ("ff_executor", "node (relative: in the bridge's namespace) whose setpoints and effort "
                      "commands need no claim while nobody holds one, when it is the topic's sole "
                      "publisher; '' = every command needs a claim (~/claim)"),
    "claim_lease": (2.0, "s, a claim expires this long after the owner's latest renewal or accepted "
                         "command (its process died or hung), unless the claim asked for another lease"),
    "claim_max_lease": (3600.0, "s, the longest lease a claim may ask for"),
    "joint_state_rate": (100.0, "Hz"),
    "diagnostics_rate": (2.0, "Hz"),
}


#: (from, to) of the scalar parameters (ints: integer range)
RANGES: dict[str, tuple[float, float]] = {
    "bus_bitrate": (10_000, 1_000_000), "sync_period": (0.0001, 1.0), "heartbeat_producer_ms": (0, 65535),
    "heartbeat_timeout": (0.0, 60.0), "master_heartbeat_ms": (0, 65535),
    "master_heartbeat_timeout_ms": (0, 65535), "master_node_id": (1, 127),
    **{k: (lo, hi) for k, lo, hi in OPTION_RANGES}, "rpdo_timeout_ms": (-1, 65535),
    "scaling_tolerance": (0.0, 1.0), "sync_timeout": (0.0, 60.0), "timeout_margin": (0.0, 10.0),
    "missed_cycle_tolerance": (0, 1000),
    "feedback_every": (1, 240), "boot_timeout": (0.0, 600.0), "boot_wait": (0.0, 3600.0),
    "setpoint_timeout": (0.0, 60.0), "feedback_timeout": (0.0, 60.0), "sdo_timeout": (0.001, 60.0),
    "state_timeout": (0.001, 600.0), "monitor_period": (0.0001, 1.0), "setpoint_lead": (0.0, 1.0),
    "stall_dump": (0.0, 3600.0),
    "spin_margin": (0.0, 0.05), "scheduler_rt_priority": (-1, 99), "joint_state_rate": (0.1, 10_000.0),
    "diagnostics_rate": (0.01, 1000.0), "claim_lease": (0.05, 3600.0), "claim_max_lease": (0.05, 86400.0),
}
#: allowed values of the string parameters
CHOICES: dict[str, str] = {
    "families": "each one of: epos4, epos2", "scaling_source": "one of: check, drive, config",
    "setpoint_timing": "one of: sync, on_receipt", "sync_producer": "one of: master, external",
}


def descriptor(name: str) -> ParameterDescriptor:
    """The ParameterDescriptor of bridge parameter ``name``: description with units, range or
    allowed values. Not read-only in the ROS sense: the node shows the configuration in use in
    them after configure; while configured, changes are refused (cleanup first)."""
    default, text = PARAMS[name]
    when = ("read at configure" if name in ("joint_state_rate", "diagnostics_rate")
            else "read at configure; refused while configured")
    d = ParameterDescriptor(name=name, description=f"{text} ({when})")
    rng = RANGES.get(name)
    if rng is not None and isinstance(default, int) and not isinstance(default, bool):
        d.integer_range = [IntegerRange(from_value=int(rng[0]), to_value=int(rng[1]), step=0)]
    elif rng is not None:
        d.floating_point_range = [FloatingPointRange(from_value=float(rng[0]), to_value=float(rng[1]), step=0.0)]
    if name in CHOICES:
        d.additional_constraints = CHOICES[name]
    return d


def parameters_markdown() -> str:
    """The Markdown table of the bridge's parameters (docs/parameters.md, between its markers)."""
    rows = ["| name | default | range / values | description |", "|---|---|---|---|"]
    for name, (default, text) in PARAMS.items():
        rng = RANGES.get(name)
        allowed = CHOICES.get(name, f"{rng[0]:g} .. {rng[1]:g}" if rng else "")
        rows.append(f"| `{name}` | `{json.dumps(default, ensure_ascii=False)}` | {allowed} | "
                    f"{text.replace('|', '/')} |")
    return "\n".join(rows) + "\n"


def _flat_config(get: Callable[[str], Any]) -> dict[str, Any]:
    """The config mapping from the flat parameters."""
    names = list(get("joint_names"))
    n = len(names)
    lists = {k: list(get(k)) for k in ("node_ids", "families", "current_limits", "nominal_currents",
                                       "torque_constants", "counts_per_rev", "gear_ratios")}
    for k, v in lists.items():
        if len(v) != n:
            raise ConfigError(f"parameter {k} has {len(v)} entries, joint_names has {n}; give one per joint")
    env = _envelopes(get, n)
    joints = [{"name": names[i], "node_id": int(lists["node_ids"][i]), "family": lists["families"][i],
               "current_limit": lists["current_limits"][i],
               "units": {"nominal_current": lists["nominal_currents"][i],
                         "torque_constant": lists["torque_constants"][i],
                         "counts_per_rev": lists["counts_per_rev"][i],
                         "gear_ratio": lists["gear_ratios"][i]}, **env[i]} for i in range(n)]
    return {"bus": {"interface": get("bus_interface") or "virtual",
                    "channel": get("bus_channel") or "ff-bridge", "bitrate": int(get("bus_bitrate"))},
            "joints": joints, "sync_period": get("sync_period"),
            "heartbeat_producer_ms": int(get("heartbeat_producer_ms")),
            "heartbeat_timeout": get("heartbeat_timeout"),
            "master_heartbeat_ms": int(get("master_heartbeat_ms")),
            "master_node_id": int(get("master_node_id")), "setpoint_timeout": get("setpoint_timeout"),
            "spin_margin": get("spin_margin"), "scheduler_rt_priority": int(get("scheduler_rt_priority")),
            **{k: get(k) for k in FLAT_DRIVE_KEYS if not (k == "rpdo_timeout_ms" and get(k) == -1)}}


#: flat parameters copied as they are into the config mapping
FLAT_DRIVE_KEYS = ("master_heartbeat_timeout_ms", "rpdo_timeout_ms", "quick_stop_option",
                   "fault_reaction_option", "abort_connection_option",
                   "communication_error_behaviour", "scaling_source", "scaling_tolerance",
                   "boot_timeout", "boot_wait", "check_identity", "setpoint_timing", "sync_producer",
                   "sync_timeout", "missed_cycle_tolerance", "feedback_every", "timeout_margin",
                   "feedback_timeout", "sdo_timeout", "state_timeout", "monitor_period",
                   "reset_communication", "player_process", "setpoint_lead", "stall_dump")


def _envelopes(get: Callable[[str], Any], n: int) -> list[dict[str, Any]]:
    """Per joint ``position_limits`` / ``velocity_limit`` from the flat lists (zeros = none)."""
    pos = [float(x) for x in get("position_limits")]
    vel = [float(x) for x in get("velocity_limits")]
    if any(pos) and len(pos) != 2 * n:
        raise ConfigError(f"parameter position_limits needs 2 values per joint ({2 * n}), got {len(pos)}")
    if any(vel) and len(vel) != n:
        raise ConfigError(f"parameter velocity_limits needs one value per joint ({n}), got {len(vel)}")
    out: list[dict[str, Any]] = [{} for _ in range(n)]
    for i in range(n):
        if any(pos) and (pos[2 * i] or pos[2 * i + 1]):
            out[i]["position_limits"] = [pos[2 * i], pos[2 * i + 1]]
        if any(vel) and vel[i]:
            out[i]["velocity_limit"] = vel[i]
    return out


def config_parameters(cfg: BridgeConfig) -> dict[str, Any]:
    """The flat parameter values of a configuration (what the node shows after configure)."""
    js = cfg.joints
    pos = [x for j in js for x in (j.position_limits or (0.0, 0.0))]
    out: dict[str, Any] = {
        "bus_interface": cfg.bus.interface, "bus_channel": cfg.bus.channel or "",
        "bus_bitrate": int(cfg.bus.bitrate), "joint_names": [j.name for j in js],
        "node_ids": [j.node_id for j in js], "families": [j.family for j in js],
        "current_limits": [float(j.current_limit) for j in js],
        "nominal_currents": [float(j.units.nominal_current) for j in js],
        "torque_constants": [float(j.units.torque_constant) for j in js],
        "counts_per_rev": [float(j.units.counts_per_rev) for j in js],
        "gear_ratios": [float(j.units.gear_ratio) for j in js],
        "position_limits": pos if any(pos) else [0.0],
        "velocity_limits": [float(j.velocity_limit or 0.0) for j in js],
    }
    for k in ("sync_period", "heartbeat_producer_ms", "heartbeat_timeout", "master_heartbeat_ms",
              "master_node_id", "setpoint_timeout", "spin_margin", "scheduler_rt_priority",
              *FLAT_DRIVE_KEYS):
        out[k] = getattr(cfg, k)
    return out


class CommandRejected(ValueError):
    """An effort command the bridge does not apply; the message says why."""


def command_currents(names: Sequence[str], effort: Sequence[float], joint_names: Sequence[str],
                     units: Sequence[DriveUnits], *, position: Sequence[float] = (),
                     velocity: Sequence[float] = ()) -> list[float]:
    """Motor currents (A, in the bridge's joint order) for a JointState effort command.

    ``effort`` is N·m at the joint, one per ``names`` entry (names of other joints are ignored;
    no names: one effort per bridge joint in its order); A = N·m / (gear_ratio x kt); a
    non-finite effort is 0 A. CommandRejected for position/velocity commands, a missing joint or
    a length mismatch."""
    if len(position) or len(velocity):
        raise CommandRejected("position/velocity commands are not supported (effort only: declare an "
                              "'effort' command interface)")
    n = len(joint_names)
    if not len(names):
        if len(effort) != n:
            raise CommandRejected(f"{len(effort)} effort value(s) without names for {n} joint(s) "
                                  f"{list(joint_names)}")
        by_name = dict(zip(joint_names, effort))
    else:
        if len(effort) != len(names):
            raise CommandRejected(f"{len(names)} name(s) but {len(effort)} effort value(s)")
        by_name = dict(zip(names, effort))
        missing = [j for j in joint_names if j not in by_name]
        if missing:
            raise CommandRejected(f"no effort for joint(s) {missing} (names {list(names)})")
    out = []
    for j, u in zip(joint_names, units):
        tau = float(by_name[j])
        out.append(tau / (u.gear_ratio * u.torque_constant) if math.isfinite(tau) else 0.0)
    return out


class _RosLogHandler(logging.Handler):
    """Forwards the libraries' python logging (ff_hwbridge.*, canopen) to the node's ROS logger."""

    def __init__(self, ros_logger: Any) -> None:
        super().__init__(logging.WARNING)
        self._ros = ros_logger

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = f"{record.name}: {record.getMessage()}"
            if record.levelno >= logging.ERROR:
                self._ros.error(text)
            else:
                self._ros.warning(text)
        except Exception:  # noqa: BLE001 - logging must never raise
            pass


class BridgeNode(LifecycleNode):
    """The ``ff_hwbridge`` lifecycle node (see the module docstring)."""

    def __init__(self, config_file: str = "", channel: str = "", **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        for name, (default, _desc) in PARAMS.items():
            self.declare_parameter(name, default, descriptor(name))
        self._override_file = config_file
        self._override_channel = channel
        self.config: Optional[BridgeConfig] = None
        self.master: Optional[EposMaster] = None
        self.player: Optional[Union[SetpointPlayer, ProcessPlayer]] = None
        self._active = False
        self._gc_thresholds: Optional[tuple[int, int, int]] = None   # held while active
        #: the process is this node's own (its entry point): configure puts all its threads under
        #: SCHED_FIFO one below the player's priority; not for a node sharing its process
        self.fifo_threads = False
        self._idle_gc = IdleCollector(self._player_idle)
        self._entities: list[tuple[str, Any]] = []
        self._interface_timers: list[Any] = []
        self._pub_js: Any = None
        self._pub_cur: Any = None
        self._pub_applied: Any = None
        self._diag_now = threading.Event()
        self._last_sample_ns = 0        # bus ns of the last published drive sample
        # who is in control of the currents: a running profile (id, latest stamp ns) or live
        # non-zero effort commands (monotonic s of the latest)
        self._profile: Optional[tuple[str, int]] = None
        self._commands_live = 0.0
        self._command_seq = 0
        self.commands_accepted = 0
        self.commands_refused = 0
        self.last_command_refusal = ""
        self._refusal_cause = ""        # logged once per cause, until a command is accepted
        self._refusal_logs: dict[str, float] = {}   # monotonic s of the latest refusal logged, per kind
        self._log_handler = _RosLogHandler(self.get_logger())
        for name in ("ff_hwbridge", "canopen"):
            logging.getLogger(name).addHandler(self._log_handler)
        self._showing_config = False
        self.add_on_set_parameters_callback(self._on_set_parameters)
        #: who may command the drives (set up at configure from default_owner, claim_lease)
        self.ownership: Optional[Ownership] = None
        # (client, token, ROS time) of the latest claim granted: ~/status's claimed_since
        self._claim_granted: Optional[tuple[str, str, Any]] = None
        self._owner_enabling = False     # an activate the owner asked for (~/owner_command ENABLE)
        self.config_error = ""           # why the latest configure failed
        self._sub_setpoints: Any = None
        self._sub_commands: Any = None
        # the typed status and the diagnostics live as long as the node: a configure that fails
        # is reported there too
        self._pub_status = self.create_publisher(DriveGroupStatus, "~/status", 10)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_timer(1.0, self._publish_unconfigured)

    # --- public state -----------------------------------------------------------------------------
    @property
    def active(self) -> bool:
        """True between a successful activate and the next deactivate / cleanup / error."""
        return self._active

    # --- helpers ----------------------------------------------------------------------------------
    def _get(self, name: str) -> Any:
        return self.get_parameter(name).value

    def _cfg(self) -> BridgeConfig:
        """The configuration in use (set by configure)."""
        if self.config is None:
            raise RuntimeError("the bridge is not configured")
        return self.config

    def _load_config(self) -> BridgeConfig:
        path = self._override_file or self._get("config_file")
        if path:
            cfg = load_config(path)
        else:
            cfg = config_from_mapping(_flat_config(self._get))
        channel = self._override_channel or (self._get("bus_channel") if path else "")
        iface = self._get("bus_interface") if path else ""
        if channel or iface:
            iface = iface or ("remote" if str(channel).startswith("ws") else cfg.bus.interface)
            bus = {"interface": iface, "bitrate": cfg.bus.bitrate}
            if channel or cfg.bus.channel:
                bus["channel"] = channel or cfg.bus.channel
            cfg = with_bus(cfg, bus)
        return cfg

    def _show_config(self, cfg: BridgeConfig) -> None:
        """Set the flat parameters to the configuration in use (they then read true)."""
        from rclpy.parameter import Parameter

        self._showing_config = True
        try:
            results = self.set_parameters([Parameter(k, value=v) for k, v in config_parameters(cfg).items()])
        finally:
            self._showing_config = False
        for r in results:
            if not r.successful:
                self.get_logger().warning(f"parameters do not show the config in use: {r.reason}")

    def _on_set_parameters(self, params: list) -> Any:
        from rcl_interfaces.msg import SetParametersResult

        if self._showing_config or self.master is None:
            return SetParametersResult(successful=True)      # applied at the next configure
        fixed = [p.name for p in params if p.name in PARAMS
                 and p.name not in ("joint_state_rate", "diagnostics_rate")]
        if fixed:
            return SetParametersResult(successful=False, reason=(
                f"{', '.join(fixed)}: applied at configure; cleanup the bridge, set them, configure again"))
        return SetParametersResult(successful=True)

    # --- lifecycle --------------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Connect and set up the drives (NMT, SDO, PDO, SYNC, heartbeat/EMCY)."""
        try:
            self.config = cfg = self._load_config()
            self.ownership = Ownership(float(self._get("claim_lease")), float(self._get("claim_max_lease")),
                                       qualified_name(str(self._get("default_owner")), self.get_namespace()))
            self._claim_granted = None
            # the long full collection before anything on the bus is timed (the watchdogs start
            # at configure); activate's, just before enabling, then scans only what came since
            freeze_heap()
            self.master = EposMaster(cfg, on_fault=self._on_fault)
            self.master.connect()
            self.master.configure()
        except (ValueError, EposError, OSError) as exc:
            self.config_error = f"configure failed: {exc}"
            self.get_logger().error(self.config_error)
            self._publish_unconfigured()
            return TransitionCallbackReturn.ERROR
        self.config_error = ""
        # player_process (sync only): guard, units, RPDO and SYNC watch in a process of its own,
        # which this node's executor (and its GIL) cannot stall; else a thread here
        kind = ProcessPlayer if cfg.player_process and cfg.synchronous else SetpointPlayer
        if cfg.rt_priority > 1 and self.fifo_threads and kind is SetpointPlayer:
            # every thread of this node's process one below the player and the bus receiver: an executor
            # thread holding the GIL is then never preempted by ordinary processes while the
            # player waits for it (threads started later inherit it). Not with the player in a
            # process of its own: nothing here is timing-critical then, and a child started
            # from a SCHED_FIFO thread would import numpy and canopen under SCHED_FIFO
            # (measured: the hub's SYNC 100-110 ms late while it did)
            got = setup_process(RealtimeConfig(priority=cfg.rt_priority - 1, switch_interval=0.0), "ff_hwbridge")
            n = got.get("fifo_threads", 0)
            if n:
                self.get_logger().info(f"SCHED_FIFO {cfg.rt_priority - 1} for the node's {n} threads, "
                                       f"{cfg.rt_priority} for the setpoint player and the bus receiver")
        self.player = kind(self.master).start()
        if isinstance(self.player, ProcessPlayer):
            self.get_logger().info(f"setpoint player in its own process (pid {self.player.pid})")
        self._show_config(cfg)
        self._make_interfaces()
        self.get_logger().info(f"configured: joints {list(cfg.joint_names)} on "
                               f"{cfg.bus.interface}:{cfg.bus.channel}")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Enable operation with zero current (transitions 2, 3, 4). While a client holds the
        drive, only its ``~/owner_command`` ENABLE activates (a lifecycle request is refused)."""
        assert self.master is not None
        if self.ownership is not None and self.ownership.claimed and not self._owner_enabling:
            d = self.ownership.authorize("enable")
            self.get_logger().warning(f"activate (lifecycle ~/change_state) refused: {d.reason}; "
                                      "the owner enables with ~/owner_command ENABLE")
            self._diag_now.set()
            return TransitionCallbackReturn.FAILURE
        # enabling the drives is the last step: from Operation enabled on, the bus receiver must
        # send the setpoint RPDO in every SYNC cycle (``EposMaster._on_cycle``), and a thread of
        # this process holding the GIL for a cycle faults the drive (EMCY 0x8250). So everything
        # that holds it for long runs first: the full collection and the heap freeze, the
        # lifecycle entities, the first publications (first-use set-up in rclpy and the middleware)
        frozen = self._prepare_for_enable()
        super().on_activate(state)
        try:
            self.master.enable()
        except EposError as exc:
            self.get_logger().error(f"activate failed: {exc}")
            return TransitionCallbackReturn.ERROR
        if not self.master.wait_for_state(State.OPERATION_ENABLED, self._cfg().state_timeout * 2):
            states = [s.value if s else "unknown" for s in self.master.states()]
            self.get_logger().error(f"activate failed: drives did not reach Operation enabled "
                                    f"(states {states}; {self.master.fault_reason or 'no fault'})")
            return TransitionCallbackReturn.ERROR
        self._active = True
        self.get_logger().info(f"active: operation enabled, accepting setpoints "
                               f"({frozen} objects frozen out of the collector's scans)")
        return TransitionCallbackReturn.SUCCESS

    def _prepare_for_enable(self) -> int:
        """What activation does before the drives are enabled; returns the frozen object count.
        What configure and activate built lives as long as the node: out of the collector's
        scans (``gc.freeze``), so that a full collection cannot hold the GIL for a SYNC cycle, and
        no automatic full collection while active (:class:`IdleCollector` runs them while no drive
        is enabled). The status, diagnostics and joint-state publications run once, so that their
        first-use costs are paid here."""
        self._publish_joint_states()
        self._publish_diagnostics()
        frozen = freeze_heap()
        if self._gc_thresholds is None:
            self._gc_thresholds = hold_full_collections()
        return frozen

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Drop pending setpoints, zero current, disable operation (transition 5)."""
        self._active = False
        self._profile, self._commands_live = None, 0.0
        if self._gc_thresholds is not None:
            gc.set_threshold(*self._gc_thresholds)
            self._gc_thresholds = None
        if self.player is not None:
            self.player.clear()
        if self.master is not None:
            self.master.disable()
            self.master.wait_for_state(State.SWITCHED_ON, self._cfg().state_timeout)
        self.get_logger().info("inactive: zero current, operation disabled")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop the player (zero current), disable voltage, stop SYNC, close the bus."""
        self.teardown()
        self.get_logger().info("cleaned up: bus closed")
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.teardown()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        reason = self.master.fault_reason if self.master else None
        self.get_logger().error(f"error processing (from '{state.label}'): closing the bus"
                                + (f"; safe state: {reason}" if reason else ""))
        self.teardown()
        return TransitionCallbackReturn.SUCCESS

    def destroy_node(self) -> None:
        for name in ("ff_hwbridge", "canopen"):
            logging.getLogger(name).removeHandler(self._log_handler)
        super().destroy_node()

    def _best_effort(self, what: str, step: Callable[[], object]) -> None:
        """Run one step of a teardown; log its failure and go on (the rest must still run)."""
        try:
            step()
        except Exception as exc:  # noqa: BLE001 - best effort on the way out
            self.get_logger().error(f"{what}: {exc}")

    def teardown(self) -> None:
        """Stop the player (zero current), close the bus, remove topics and timers (idempotent)."""
        self._active = False
        self.ownership = None
        if self.player is not None:
            self._best_effort("stopping the setpoint player", self.player.close)
            self.player = None
        if self.master is not None:
            self._best_effort("disconnect", self.master.disconnect)
            self.master = None
        for t in self._interface_timers:
            self.destroy_timer(t)
        self._interface_timers.clear()
        for kind, ent in self._entities:
            if kind == "pub":
                self.destroy_publisher(ent)
            elif kind == "sub":
                self.destroy_subscription(ent)
            else:
                self.destroy_service(ent)
        self._entities.clear()

    # --- interfaces -------------------------------------------------------------------------------
    def _make_interfaces(self) -> None:


        self._pub_js = self.create_publisher(JointState, "~/joint_states", 10)
        self._pub_cur = self.create_publisher(JointState, "~/motor_currents", 10)
        self._pub_applied = self.create_publisher(CurrentSetpoint, "~/applied", 100)
        # own callback groups: a fault reset (which waits for the drives) or a timer never
        # holds up the intake of setpoints
        sub = self._sub_setpoints = self.create_subscription(
            CurrentSetpoint, "~/setpoints", self._on_setpoint, 100, callback_group=MutuallyExclusiveCallbackGroup())
        self._wake = self.create_guard_condition(lambda: None)   # resumes awaited work (ff_msgs_py.threads)
        srv = self.create_service(Trigger, "~/fault_reset", self._on_fault_reset,
                                  callback_group=MutuallyExclusiveCallbackGroup())
        estop_sub = self.create_subscription(Bool, "~/emergency_stop", self._on_estop_topic, 10,
                                             callback_group=MutuallyExclusiveCallbackGroup())
        self._entities.append(("sub", estop_sub))
        estop = self.create_service(Trigger, "~/estop", self._on_estop,
                                    callback_group=MutuallyExclusiveCallbackGroup())
        claim = self.create_service(ClaimDrive, "~/claim", self._on_claim,
                                    callback_group=MutuallyExclusiveCallbackGroup())
        owner_cmd = self.create_service(OwnerCommand, "~/owner_command", self._on_owner_command,
                                        callback_group=MutuallyExclusiveCallbackGroup())
        self._entities += [("pub", self._pub_js), ("pub", self._pub_cur), ("pub", self._pub_applied),
                           ("sub", sub), ("srv", srv), ("srv", estop), ("srv", claim), ("srv", owner_cmd)]
        topic = str(self._get("command_topic"))
        if topic:
            # best effort: takes reliable and best-effort publishers; the newest command wins
            cmd = self._sub_commands = self.create_subscription(
                JointState, topic, self._on_command, qos_profile_sensor_data,
                callback_group=MutuallyExclusiveCallbackGroup())
            self._entities.append(("sub", cmd))
        self._interface_timers.append(self.create_timer(1.0 / float(self._get("joint_state_rate")),
                                              self._publish_joint_states))
        self._interface_timers.append(self.create_timer(1.0 / float(self._get("diagnostics_rate")),
                                              self._publish_diagnostics))
        self._interface_timers.append(self.create_timer(0.01, self._fast_tick))

    def _on_setpoint(self, msg: Any) -> None:
        player = self.player
        if player is None:
            return
        if not self._active:
            self.get_logger().warning("setpoint ignored: bridge is not active",
                                      throttle_duration_sec=1.0)
            return
        if not self._authorized("setpoint", str(msg.token), self._sub_setpoints):
            return
        stamp_ns = int(msg.stamp.sec) * 1_000_000_000 + int(msg.stamp.nanosec)
        pid = str(msg.profile_id)
        live = time.monotonic() - self._commands_live
        if pid and live < self._cfg().setpoint_timeout:
            self.get_logger().warning(
                f"setpoint {msg.seq} of profile {pid} ignored: effort commands on "
                f"{self._get('command_topic')} are in control ({live * 1000.0:.0f} ms ago); "
                "send zero effort or stop them first", throttle_duration_sec=1.0)
            return
        try:
            player.submit(stamp_ns, list(msg.currents), seq=int(msg.seq),
                          profile_id=pid, last=bool(msg.last))
            if pid:
                self._profile = (pid, stamp_ns)
        except SetpointRejected as exc:
            if player.master.latched:
                text = f"setpoint ignored: {exc}; call ~/fault_reset"
            else:
                text = f"setpoint {msg.seq} ignored: {exc}"
            self.get_logger().warning(text, throttle_duration_sec=1.0)

    def _player_idle(self) -> bool:
        """Nothing queued or in flight, no profile running: a full collection harms no timing."""
        return self.player is None or (self.player.pending == 0 and not self._profile_running())

    def _profile_running(self) -> Optional[str]:
        """The id of the profile in control of the currents, or None: from its first setpoint
        until its last one is applied, the safe state latches, or its latest stamp is
        ``setpoint_timeout`` s past with nothing pending."""
        prof, player = self._profile, self.player
        if prof is None or player is None:
            return None
        if player.master.latched or (time.time_ns() > prof[1] + int(self._cfg().setpoint_timeout * 1e9)
                                     and player.pending == 0):
            self._profile = None
            return None
        return prof[0]

    def _refuse_command(self, cause: str, text: str) -> None:
        """Count a refused effort command; log it once per cause (until one is accepted)."""
        self.commands_refused += 1
        self.last_command_refusal = text
        if cause != self._refusal_cause:
            self._refusal_cause = cause
            self.get_logger().warning(f"effort command ignored: {text}")

    def _on_command(self, msg: Any) -> None:
        """An effort command (JointState, N·m at the joint) -> motor currents at once."""
        player = self.player
        if player is None:
            return
        if not self._active:
            self._refuse_command("inactive", "bridge is not active")
            return
        if not self._authorized("command", str(msg.header.frame_id), self._sub_commands):
            return
        profile = self._profile_running()
        if profile is not None:
            self._refuse_command("profile", f"profile {profile} is running (a CurrentProfile and effort "
                                 "commands never drive the arm at the same time)")
            return
        try:
            amps = command_currents(list(msg.name), list(msg.effort), self._cfg().joint_names,
                                    player.master.units, position=list(msg.position),
                                    velocity=list(msg.velocity))
            player.submit(time.time_ns(), amps, seq=self._command_seq)
        except CommandRejected as exc:
            self._refuse_command("message", str(exc))
            return
        except SetpointRejected as exc:
            self._refuse_command("rejected", f"{exc}; call ~/fault_reset")
            return
        self._command_seq += 1
        self.commands_accepted += 1
        self._refusal_cause = ""
        self._commands_live = time.monotonic() if any(a != 0.0 for a in amps) else 0.0

    def _on_fault(self, reason: str) -> None:
        """Master thread: safe state latched (the player drops its pending setpoints itself)."""
        self._commands_live = 0.0         # latched: nothing is in control until a fault reset
        self._diag_now.set()              # the reason is logged by the master (forwarded)

    def _on_estop(self, request: Any, response: Any) -> Any:
        """Service ~/estop: latch the safe state now (no waiting)."""
        master = self.master
        if master is None:
            response.success, response.message = False, "bridge is not configured"
            return response
        reason = master.estop("service ~/estop")
        response.success, response.message = True, f"safe state: {reason}"
        self.get_logger().error(f"e-stop: {response.message}")
        self._diag_now.set()
        return response

    def _on_estop_topic(self, msg: Any) -> None:
        """Topic ~/emergency_stop: ``true`` latches the safe state now, as the service does."""
        master = self.master
        if not bool(msg.data) or master is None:
            return
        if master.latched:
            return                         # already stopped; the first reason stays
        reason = master.estop("topic ~/emergency_stop")
        self.get_logger().error(f"e-stop: safe state: {reason}")
        self._diag_now.set()

    async def _on_fault_reset(self, request: Any, response: Any) -> Any:
        """Service ~/fault_reset: waits for the drive on its own thread (ff_msgs_py.threads).
        Open to anyone while no client holds a claim; refused while one does (the owner resets
        with ~/owner_command FAULT_RESET)."""
        if self.ownership is not None and self.ownership.claimed:
            d = self.ownership.authorize("fault_reset")
            self.get_logger().warning(f"~/fault_reset refused: {d.reason}; the owner resets with "
                                      "~/owner_command FAULT_RESET")
            self._diag_now.set()
            response.success, response.message = False, d.reason
            return response
        return await in_thread(self._fault_reset, response, wake=self._wake, name="ff_fault_reset")

    # --- ownership --------------------------------------------------------------------------------
    def _sole_publisher(self, sub: Any) -> str:
        """The node publishing on ``sub``'s topic when it is the only one there, else "" (two
        publishers, or a node whose name discovery has not yet told): a token-less message is
        then certainly that node's."""
        if sub is None:
            return ""
        names = {qualified_name(e.node_name, e.node_namespace)
                 for e in self.get_publishers_info_by_topic(sub.topic_name)}
        name = names.pop() if len(names) == 1 else ""
        return "" if "_NODE_NAME_UNKNOWN_" in name else name

    def _authorized(self, kind: str, token: str, sub: Any) -> bool:
        """May this setpoint / effort command move the arm? A refusal is counted and logged."""
        own = self.ownership
        if own is None:
            return False
        sender = "" if token or own.claimed or not own.default_owner else self._sole_publisher(sub)
        d = own.authorize(kind, token, sender)
        if not d.accepted:
            self._refusal_logs.setdefault(kind, 0)
            now = time.monotonic()
            if now - self._refusal_logs[kind] >= 1.0:      # at most once a second per kind
                self._refusal_logs[kind] = now
                self.get_logger().warning(f"{d.reason} ({own.refused[kind]} refused so far)")
            self._diag_now.set()
        return d.accepted

    def _motion_live(self) -> bool:
        """A profile runs or non-zero effort commands are live (a claim change must wait)."""
        live = time.monotonic() - self._commands_live < self._cfg().setpoint_timeout
        return self._profile_running() is not None or live

    def _on_claim(self, request: Any, response: Any) -> Any:
        """Service ~/claim (ff_msgs/srv/ClaimDrive): CLAIM, RENEW, RELEASE."""
        own = self.ownership
        response.success = False
        if own is None:
            response.message = "bridge is not configured"
            return response
        try:
            if request.action == ClaimDrive.Request.CLAIM:
                if not own.claimed and self._motion_live():
                    raise ClaimRefused(f"a motion of {own.owner or 'another client'} is running; claim "
                                       "after it ends")
                c = own.claim(str(request.client), float(request.lease), str(request.token))
                if self._claim_granted is None or self._claim_granted[1] != c.token:
                    self._claim_granted = (c.client, c.token, self.get_clock().now().to_msg())
                response.token, response.lease = c.token, c.lease
                response.message = f"claimed by {c.client} (lease {c.lease:g} s)"
                self.get_logger().info(f"drive {response.message}")
            elif request.action == ClaimDrive.Request.RENEW:
                c = own.renew(str(request.token))
                response.lease, response.message = c.lease, f"renewed for {c.client} ({c.lease:g} s)"
            elif request.action == ClaimDrive.Request.RELEASE:
                live = self.master is not None and self._motion_live()
                c = own.release(str(request.token))
                response.message = f"released by {c.client}"
                self.get_logger().info(f"drive {response.message}")
                if live and self.master is not None:
                    self.master.quick_stop(f"{c.client} released the drive during a motion")
            else:
                raise ClaimRefused(f"unknown action {request.action} (CLAIM 0, RENEW 1, RELEASE 2)")
            response.success = True
        except ClaimRefused as exc:
            response.message = str(exc)
            self.get_logger().warning(f"claim request refused: {exc}")
        response.owner = own.owner
        self._diag_now.set()
        return response

    async def _on_owner_command(self, request: Any, response: Any) -> Any:
        """Service ~/owner_command (ff_msgs/srv/OwnerCommand): the owner's FAULT_RESET or ENABLE."""
        own = self.ownership
        if own is None or self.master is None:
            response.success, response.message = False, "bridge is not configured"
            return response
        kind = {OwnerCommand.Request.FAULT_RESET: "fault_reset",
                OwnerCommand.Request.ENABLE: "enable"}.get(request.command)
        if kind is None:
            response.success, response.message = False, f"unknown command {request.command}"
            return response
        d = own.authorize(kind, str(request.token))
        if not d.accepted:
            self.get_logger().warning(f"~/owner_command: {d.reason}")
            self._diag_now.set()
            response.success, response.message = False, d.reason
            return response
        if kind == "fault_reset":
            return await in_thread(self._fault_reset, response, wake=self._wake, name="ff_fault_reset")
        return await in_thread(self._owner_enable, response, wake=self._wake, name="ff_enable")

    def _owner_enable(self, response: Any) -> Any:
        if self._active:
            response.success, response.message = True, "already active"
            return response
        self._owner_enabling = True
        try:
            self.trigger_activate()
        finally:
            self._owner_enabling = False
        response.success = self._active
        response.message = "active: operation enabled" if self._active else "activate failed (see the log)"
        self._diag_now.set()
        return response

    def _expire_claim(self) -> None:
        """A claim whose lease ran out: log it; during a motion, latch the safe state."""
        own = self.ownership
        gone = own.expire() if own is not None else None
        if gone is None:
            return
        self.get_logger().warning(f"claim of {gone.client} expired: no renewal or accepted command for "
                                  f"{gone.lease:g} s")
        if self.master is not None and self._motion_live():
            self.master.quick_stop(f"claim of {gone.client} expired during a motion")
        self._diag_now.set()

    def _fault_reset(self, response: Any) -> Any:
        if self.master is None:
            response.success, response.message = False, "bridge is not configured"
            return response
        old = self.master.fault_reset(reenable=self._active)
        ok = not self.master.latched
        if ok and self._active:
            ok = self.master.wait_for_state(State.OPERATION_ENABLED, self._cfg().state_timeout)
        response.success = bool(ok)
        response.message = (f"cleared: {old or 'nothing latched'}" if ok else
                            f"fault reset did not recover: {self.master.fault_reason or 'drive state'}")
        self.get_logger().info(f"fault reset: {response.message}")
        self._diag_now.set()
        return response

    def _fast_tick(self) -> None:

        self._expire_claim()
        reports: list[AppliedSetpoint] = self.player.take_applied() if self.player else []
        for a in reports:
            if a.last and self._profile is not None and a.profile_id == self._profile[0]:
                self._profile = None
            if a.reason and not a.latched:
                self.get_logger().warning(f"setpoint {a.seq}: {a.reason}", throttle_duration_sec=1.0)
            msg = CurrentSetpoint()
            msg.stamp.sec, msg.stamp.nanosec = divmod(a.sent_ns, 1_000_000_000)
            msg.currents, msg.seq, msg.profile_id, msg.last = list(a.currents), a.seq, a.profile_id, a.last
            self._pub_applied.publish(msg)
            if a.last:                    # the executor's result waits for the move's timing counts
                self._diag_now.set()
        if self._diag_now.is_set():
            self._diag_now.clear()
            self._publish_diagnostics()

    def _publish_joint_states(self) -> None:
        """One JointState (effort N·m) and one motor-current JointState (effort A) per new drive
        sample, stamped with the instant of the latest position sample (its SYNC)."""
        if self.master is None:
            return
        fb = self.master.feedback()
        sample_ns = max((f.sample_ns for f in fb), default=0)
        if sample_ns == 0 or sample_ns == self._last_sample_ns:
            return                      # nothing new from the drives: no repeated sample
        self._last_sample_ns = sample_ns
        units = self.master.units
        msgs = (JointState(), JointState())
        for msg in msgs:
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(sample_ns, 1_000_000_000)
            msg.name = list(self._cfg().joint_names)
            msg.position = [f.position for f in fb]
            msg.velocity = [f.velocity for f in fb]
        msgs[0].effort = [u.joint_torque(f.current) for u, f in zip(units, fb)]
        msgs[1].effort = [f.current for f in fb]
        self._pub_js.publish(msgs[0])
        self._pub_cur.publish(msgs[1])

    def _publish_diagnostics(self) -> None:
        """The drive group's status on /diagnostics; a failure is logged, never ends the node."""
        try:
            self._publish_diagnostics_now()
        except Exception as exc:  # noqa: BLE001 - a report must not take the executor down
            self.get_logger().error(f"diagnostics not published: {type(exc).__name__}: {exc}",
                                    throttle_duration_sec=5.0)

    def _publish_diagnostics_now(self) -> None:
        if self.master is None:
            return
        st = self.master.status()
        if self.player is not None:
            st.update(self.player.diagnostics())
        pause_ms = self._idle_gc.tick()
        # with the heap frozen at activate a full collection scans only what was built since
        # (measured 0.1-0.8 ms in an active bridge); one that holds the GIL for a sizeable part
        # of a SYNC cycle risks the per-cycle RPDO (EMCY 0x8250): said, so that it is seen
        if pause_ms is not None and pause_ms > 250.0 * self._cfg().sync_period:
            self.get_logger().warning(f"idle full garbage collection took {pause_ms:.1f} ms "
                                      f"(SYNC period {self._cfg().sync_period * 1e3:.1f} ms)")
        st.update(gc_pauses.as_dict())
        st["gc.idle_collections"] = self._idle_gc.collections
        st["active"] = self._active
        st["commands.topic"] = self._get("command_topic")
        st["commands.accepted"] = self.commands_accepted
        st["commands.refused"] = self.commands_refused
        st["commands.last_refusal"] = self.last_command_refusal
        st["profile_running"] = self._profile_running() or ""
        if self.ownership is not None:
            st.update(self.ownership.status())
        status = DiagnosticStatus()
        status.name = self._status_name()
        status.hardware_id = ",".join(f"node{j.node_id}" for j in self._cfg().joints)
        if self.master.latched:
            status.level, status.message = DiagnosticStatus.ERROR, f"safe state: {self.master.fault_reason}"
        elif not self._active:
            status.level, status.message = DiagnosticStatus.WARN, "not active"
        elif any(v for k, v in st.items() if k.endswith(".motion_limited_count")):
            limited = [k[:-len(".motion_limited_count")] for k, v in st.items()
                       if k.endswith(".motion_limited_count") and v]
            status.level = DiagnosticStatus.WARN
            status.message = ("operation enabled; the drive clipped the latest motion's current "
                              f"(statusword bit 11: {', '.join(limited)})")
        elif any(v is True for k, v in st.items() if k.endswith(".warning")):
            warn = [str(v) for k, v in st.items() if k.endswith(".last_warning") and v]
            status.level = DiagnosticStatus.WARN
            status.message = "operation enabled; drive warning" + (f": {warn[-1]}" if warn else "")
        else:
            status.level, status.message = DiagnosticStatus.OK, "operation enabled"
        status.values = [KeyValue(key=str(k), value=str(v)) for k, v in st.items()]
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [status]
        self._pub_diag.publish(arr)
        self._publish_status(status, st)

    def _publish_status(self, diag: Any, st: dict[str, Any]) -> None:
        """The typed ~/status beside the /diagnostics one (same message)."""
        msg = DriveGroupStatus()
        msg.stamp = self.get_clock().now().to_msg()
        msg.message = str(diag.message)
        msg.config_error = self.config_error
        if self.master is None:
            msg.state = DriveGroupStatus.UNCONFIGURED
            self._pub_status.publish(msg)
            return
        latched = bool(self.master.latched)
        msg.state = (DriveGroupStatus.SAFE_STATE if latched else
                     DriveGroupStatus.ACTIVE if self._active else DriveGroupStatus.INACTIVE)
        msg.latch_reason = str(self.master.fault_reason or "") if latched else ""
        names = list(self._cfg().joint_names)
        msg.joint_names = names
        msg.drive_states = [str(st.get(f"{n}.state", "unknown")) for n in names]
        msg.last_emcy = [str(st.get(f"{n}.last_emcy", "")) for n in names]
        own = self.ownership
        if own is not None:
            msg.owner, msg.claimed, msg.lease_left = own.owner, own.claimed, own.lease_left()
            granted = self._claim_granted
            if msg.claimed and granted is not None and granted[0] == msg.owner:
                msg.claimed_since = granted[2]        # else zero: unclaimed
            msg.refused = sum(own.refused.values()) + own.claims_refused
            msg.last_refusal = own.last_refusal
        msg.commands_accepted = int(self.commands_accepted)
        msg.missed_setpoints = int(_count(st.get("missed_setpoints", 0)))
        # the master's statusword bit-11 count of the latest motion, per joint
        msg.current_limited_cycles = [int(_count(st.get(f"{n}.motion_limited_count", 0))) for n in names]
        msg.sync_period = float(self._cfg().sync_period) if self._cfg().synchronous else 0.0
        self._pub_status.publish(msg)

    def _status_name(self) -> str:
        """``ff_hwbridge: drive group``; under a namespace ``arm_a/ff_hwbridge: drive group``."""
        return f"{self.get_fully_qualified_name().lstrip('/')}: drive group"

    def _publish_unconfigured(self) -> None:
        """Unconfigured: /diagnostics and ~/status say so, with the reason of a failed configure."""
        if self.master is not None:
            return
        status = DiagnosticStatus(name=self._status_name())
        if self.config_error:
            status.level, status.message = DiagnosticStatus.ERROR, self.config_error
        else:
            status.level, status.message = DiagnosticStatus.WARN, "unconfigured"
        status.values = [KeyValue(key="config_error", value=self.config_error)]
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [status]
        self._pub_diag.publish(arr)
        self._publish_status(status, {})


def _count(value: Any) -> float:
    """A number from a diagnostics value (0 when it is none)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return 0.0


def main(argv: Optional[Sequence[str]] = None) -> None:
    """Console script ``ff-hwbridge [--autostart] [--config PATH] [--channel URL] [--ros-args ...]``."""

    argv = list(sys.argv if argv is None else ["ff-hwbridge", *argv])
    ap = argparse.ArgumentParser(prog="ff-hwbridge", description="CANopen bridge to Maxon EPOS drives "
                                 "(ROS 2 lifecycle node ff_hwbridge).")
    ap.add_argument("--autostart", action="store_true", help="configure and activate at start")
    ap.add_argument("--config", default="", help="bridge YAML (overrides the config_file parameter)")
    ap.add_argument("--channel", default="", help="bus channel override, e.g. ws://127.0.0.1:54701/")
    args = ap.parse_args(remove_ros_args(argv)[1:])
    # the process's real-time set-up, in one place: the bus receiver and the setpoint player get
    # the GIL back from the executor's threads within SWITCH_INTERVAL (python's default 5 ms is
    # half a 10 ms SYNC cycle), and every collection is timed for the diagnostics; SCHED_FIFO
    # (rt_priority) is applied at configure, once the player's placement is known
    setup_process(RealtimeConfig(switch_interval=SWITCH_INTERVAL, time_gc=True), "ff_hwbridge")
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        node = BridgeNode(config_file=args.config, channel=args.channel)
        node.fifo_threads = True
        # one executor thread: no callback waits on another callback (blocking work runs
        # on its own thread, ff_msgs_py.threads), and rclpy's MultiThreadedExecutor costs ~4x
        # the CPU per message (measured 47 % vs 11 % for 200 JointState/s in and out)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        if args.autostart:
            node.trigger_configure()
            if node.master is None:
                print("ff_hwbridge: configure failed (see the log above)", flush=True)
                raise SystemExit(1)
            # the executor's first passes (its threads, the wait set, the timers' and discovery's
            # first callbacks) before the drives are enabled, not in their first SYNC cycles
            executor.spin_until_future_complete(Future(), timeout_sec=AUTOSTART_SETTLE_S)
            node.trigger_activate()
            if not node.active:
                print("ff_hwbridge: activate failed (see the log above)", flush=True)
                raise SystemExit(1)
        node.get_logger().info(f"{READY_LINE}: {'active' if node.active else 'unconfigured'}")
        spin(executor, node.get_logger())
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        shut_down(node, BridgeNode.teardown)


if __name__ == "__main__":
    main()

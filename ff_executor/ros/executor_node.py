"""ROS 2 node ``ff_executor``: the action server ``~/execute`` (ff_msgs/action/ExecuteProfile).

A thin adapter around :mod:`ff_executor.engine`. For each goal it

1. checks the profile (joint names, current limits, times, step count) and that the bridge's
   lifecycle state is *active* (``/<bridge_node>/get_state``) and the arm is at rest at q0;
2. streams stamped setpoints to ``setpoint_topic``, each ``lead_time`` s before its stamp (the
   bridge applies them at their stamps: its timing, not ours, decides the switch moments);
3. sends feedback at ``feedback_rate`` Hz (elapsed s, commanded A, measured rad and rad/s);
4. after tf waits until the arm has settled (|velocity| <= ``rest_velocity`` for
   ``settle_hold`` s, at most ``settle_timeout`` s), then returns final position and velocity,
   the error to the goal and the switch-time statistics.

Refusals. A goal is refused, and no current is sent, when the profile is bad, another client
holds the drive (the bridge's typed status ``<bridge>/status``, ff_msgs/msg/DriveGroupStatus,
shows a claim of ``<bridge>/claim`` by another node: the message names it and since when this
node saw it; the bridge would refuse our setpoints), the bridge is not active, the arm is not at
rest at q0, or another goal is running. Without a claim the executor is the bridge's default
owner and its setpoints carry no token.

Names. ``bridge_node`` relative (the default ``ff_hwbridge``) is the bridge in this node's
namespace: started as ``/arm_a/ff_executor`` it watches ``/arm_a/ff_hwbridge``. The topic
parameters are used as given (``ff-bringup --namespace`` passes them inside the namespace). By default
(``refuse_mode: abort``) the goal is accepted and at once aborted with ``success = false`` and the
reason in ``message`` — ROS 2 goal rejections cannot carry a reason, and a client should learn
what to change. ``refuse_mode: reject`` rejects such goals at the goal-request stage instead (the
reason goes to this node's log only). A second goal while one runs is refused, never queued: a
queued feedforward move would start from wherever the first one ended.

Cancel → a zero-current setpoint stamped *now* at once (plus a zero after any setpoint already
handed to the bridge), then the goal ends as cancelled with the measured state. Losing the joint
states during a move (``joint_state_timeout``) stops it the same way and aborts.

Switch-time statistics come from the bridge's reports of applied setpoints on ``applied_topic``
(ff_msgs/msg/CurrentSetpoint whose stamp is the moment it was applied) when it publishes them,
else they are estimated from the measured motor currents (``current_topic``, JointState effort
A) — coarse, bounded by the joint-state period — and labelled so in the log.

The result also carries the model's rest position for the profile (``predicted_position``, from
``profile.predicted_rest``; empty when the profile does not say), the drives' SYNC period
(``sync_period``, s) and the setpoints that took effect one or more SYNC cycles late
(``missed_cycles``). Both come from the bridge's drive-group status on ``/diagnostics``:
``sync_period`` from ``sync_period_s``, else ``sync_period_us`` when ``synchronous`` is 1 (0 =
setpoints applied on receipt, also when neither is there); ``missed_cycles`` is counted from the
the increase over the goal of the status counter ``missed_setpoints`` (or ``missed_cycles``), read
from a status sent after the last applied report (the result waits up to ``DIAG_WAIT`` s for one);
without a counter it is counted from the applied reports, whose stamps are then SYNC instants
(applied − stamp ≥ 1.1 SYNC periods: :func:`ff_executor.engine.missed_cycles`).

Clipping is a failed move: when the bridge's status (from after the move's end, waited for at
most ``DIAG_WAIT`` s) counts feedback samples with statusword bit 11 (internal limit active) in
this motion (``<joint>.motion_limited_count``, first one at ``<joint>.motion_limited_first_ns``),
the drive did not apply the planned current: the goal is aborted with ``success = false``, the
message naming the joints, how many samples and from when, the measured state filled in as for
a success (:mod:`ff_executor.engine.clipping`).
"""
from __future__ import annotations

import sys
import threading
import time
from collections import deque
from typing import Any, Callable, Optional

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from lifecycle_msgs.srv import GetState
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState

from ff_executor.engine import (NS, EngineConfig, Motion, ProfileRejected, Setpoint, SettleDetector, Stream,
                                StreamRunner, TimingStats, build_setpoints, check_profile, check_start_state,
                                estimate_applied_times, missed_cycles, resolve_start, timing_stats)
from ff_executor.engine.clipping import clipped_joints, clipping_message
from ff_executor.engine.config import EXECUTOR_PARAMETERS
from ff_executor.engine.paramspec import ParamTable
from ff_msgs.action import ExecuteProfile
from ff_msgs.msg import CurrentSetpoint, DriveGroupStatus
from ff_msgs_py.convert import msg_to_profile, predicted_rest_of, setpoint_msg, time_to_ns
from ff_msgs_py.shutdown import shut_down
from ff_msgs_py.threads import in_thread
from ff_msgs_py.spin import spin

READY_LINE = "ff_executor ready"

#: s, the longest the result waits for a bridge status newer than the last applied report
DIAG_WAIT = 0.6
#: s, the longest the result waits for the bridge's reports of the move's last current changes
APPLIED_WAIT = 1.0
#: Every parameter of this node, with its default, unit, range and description (the single
#: source: ``config/executor.yaml`` and ``docs/parameters.md`` are written from it).
PARAMETERS: ParamTable = EXECUTOR_PARAMETERS


def _number(values: dict[str, str], key: str, default: Optional[float] = 0.0) -> Any:
    """A finite number from a diagnostics key/value map, else ``default``."""
    try:
        x = float(values[key])
    except (KeyError, ValueError):
        return default
    return x if np.isfinite(x) else default


def qualified(name: str, namespace: str) -> str:
    """The fully qualified node name of ``name``: itself when absolute, else in ``namespace``."""
    name = name.strip()
    return name if name.startswith("/") else f"{namespace.rstrip('/')}/{name}"


def claim_refusal(status: Any, me: str, since_ns: int, now_ns: int) -> str:
    """Why a goal cannot run while the bridge's typed ``status`` (ff_msgs/msg/DriveGroupStatus)
    shows a claim held by another client than ``me`` ("" = none does); ``since_ns``/``now_ns``:
    ns (ROS clock) when the claim was first seen and now."""
    if status is None or not status.claimed or not status.owner or status.owner == me:
        return ""
    since = time.strftime("%H:%M:%S", time.gmtime(since_ns / NS)) + f".{since_ns // 1_000_000 % 1000:03d} UTC"
    return (f"the drive is claimed by {status.owner} (since {since}, {max(now_ns - since_ns, 0) / NS:.1f} s; "
            f"lease {status.lease_left:.1f} s left): its setpoints alone move the arm, ours would be refused; "
            "wait until it releases the claim (or its lease runs out)")


def descriptor(name: str) -> ParameterDescriptor:
    """The ParameterDescriptor of executor parameter ``name``: "<unit>, <description>", range or
    allowed values, and read-only for the parameters read at start."""
    spec = PARAMETERS[name]
    d = ParameterDescriptor(name=name, description=spec.text(), read_only=spec.read_at_start)
    if spec.choices:
        d.additional_constraints = f"one of: {', '.join(spec.choices)}"
    rng, default = spec.range, spec.default
    if rng is not None and isinstance(default, int) and not isinstance(default, bool):
        d.integer_range = [IntegerRange(from_value=int(rng[0]), to_value=int(rng[1]), step=0)]
    elif rng is not None and isinstance(default, float):
        d.floating_point_range = [FloatingPointRange(from_value=float(rng[0]), to_value=float(rng[1]), step=0.0)]
    if spec.read_at_start:
        d.description += " (read at start)"
    return d


class ExecutorNode(Node):
    """Node ``ff_executor`` serving ``~/execute``; see the module docstring."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("ff_executor", **kwargs)
        for spec in PARAMETERS:
            self.declare_parameter(spec.name, spec.ros_default, descriptor(spec.name))
        g = self._p
        self.config = EngineConfig.from_parameters({name: g(name) for name in PARAMETERS.names()})
        PARAMETERS["refuse_mode"].check(g("refuse_mode"))
        self.add_on_set_parameters_callback(self._on_set_parameters)
        if not g("feedback_rate") >= 10.0:
            self.get_logger().warn("feedback_rate below 10 Hz requested; using 10 Hz")

        self._busy = threading.Lock()
        self._running_id: Optional[str] = None
        self._state_lock = threading.Lock()
        self._pos: Optional[np.ndarray] = None    # rad, bridge joint order
        self._vel: Optional[np.ndarray] = None    # rad/s
        self._state_t = 0                         # ns (ROS clock) of the last joint state
        self._sample_ns = 0                       # ns: its sample instant (header stamp; else arrival)
        self._effort_log: Optional[deque[tuple[int, np.ndarray]]] = None  # (t ns, effort A) while a move runs
        self._applied: dict[tuple[str, int], int] = {}
        self._active_stream: Optional[Stream] = None
        self._sync_period = 0.0                   # s, the bridge's SYNC period for setpoints (0 = on receipt)
        self._bridge_missed: Optional[int] = None  # the bridge's missed-cycle counter, when it reports one
        self._applied_rx_ns = 0                   # ns (ROS clock): the last applied report arrived
        self._diag_rx_ns = 0                      # ns: the last status of the bridge arrived
        self._bridge_latch = ""                   # the bridge's safe-state message ("" = none)
        self._latch_seen_ns = 0                   # ns: the last status that said "safe state" arrived
        self._diag_values: dict[str, str] = {}    # the bridge's latest drive-group status (key -> value)
        self._status: Optional[Any] = None        # the bridge's latest typed status (DriveGroupStatus)
        self._status_rx_ns = 0                    # ns: it arrived
        self._claim_since: tuple[str, int] = ("", 0)   # (claimant, ns of the first status showing its claim)

        sensor_qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT,
                                history=HistoryPolicy.KEEP_LAST)
        setpoint_qos = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE,
                                  history=HistoryPolicy.KEEP_LAST)
        self._io_group = MutuallyExclusiveCallbackGroup()
        self._client_group = ReentrantCallbackGroup()
        self._pub = self.create_publisher(CurrentSetpoint, g("setpoint_topic"), setpoint_qos)
        self._effort_from_states = not str(g("current_topic"))
        self.create_subscription(JointState, g("joint_state_topic"), self._on_joint_state,
                                 sensor_qos, callback_group=self._io_group)
        if not self._effort_from_states:
            self.create_subscription(JointState, g("current_topic"), self._on_currents,
                                     sensor_qos, callback_group=self._io_group)
        self.create_subscription(CurrentSetpoint, g("applied_topic"), self._on_applied,
                                 setpoint_qos, callback_group=self._io_group)
        self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10,
                                 callback_group=self._io_group)
        # the bridge's name: a relative one lies in this node's namespace (arm_a/ff_hwbridge)
        self.config_bridge = str(g("bridge_node"))
        self.bridge_fqn = qualified(self.config_bridge, self.get_namespace())
        self.create_subscription(DriveGroupStatus, f"{self.bridge_fqn}/status", self._on_status, 10,
                                 callback_group=self._io_group)
        self._state_client = self.create_client(GetState, f"{self.bridge_fqn}/get_state",
                                                callback_group=self._client_group)
        self._wake = self.create_guard_condition(lambda: None)   # resumes awaited work (ff_msgs_py.threads)
        self._server = ActionServer(
            self, ExecuteProfile, "~/execute", execute_callback=self._execute_in_thread,
            goal_callback=self._on_goal, cancel_callback=self._on_cancel,
            callback_group=ReentrantCallbackGroup())

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        """Refuse a runtime value outside its parameter's allowed choices (ROS checks the ranges)."""
        for p in params:
            if p.name in PARAMETERS:
                try:
                    PARAMETERS[p.name].check(p.value)
                except ValueError as exc:
                    return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _p(self, name: str) -> Any:
        return self.get_parameter(name).value

    def _now_ns(self) -> int:
        return int(self.get_clock().now().nanoseconds)

    # --- inputs -------------------------------------------------------------------------------
    def _joint_arrays(self, msg: JointState) -> Optional[tuple[np.ndarray, np.ndarray, Optional[np.ndarray]]]:
        """(position rad, velocity rad/s, effort or None) in this executor's joint order, or None."""
        names = list(msg.name)
        order = self.config.joint_names
        try:
            idx = [names.index(n) for n in order] if names else list(range(len(order)))
            pos = np.array([msg.position[i] for i in idx], dtype=float)
            vel = (np.array([msg.velocity[i] for i in idx], dtype=float)
                   if len(msg.velocity) >= len(names or order) else np.zeros(len(order)))
            eff = (np.array([msg.effort[i] for i in idx], dtype=float)
                   if len(msg.effort) >= len(names or order) else None)
        except (ValueError, IndexError):
            return None
        return pos, vel, eff

    def _log_effort(self, msg: JointState, eff: Optional[np.ndarray], now: int) -> None:
        if self._effort_log is not None and eff is not None:
            self._effort_log.append((time_to_ns(msg.header.stamp) or now, eff))

    def _on_joint_state(self, msg: JointState) -> None:
        arrays = self._joint_arrays(msg)
        if arrays is None:
            return
        pos, vel, eff = arrays
        now = self._now_ns()
        with self._state_lock:
            self._pos, self._vel, self._state_t = pos, vel, now
            self._sample_ns = time_to_ns(msg.header.stamp) or now
            if self._effort_from_states:
                self._log_effort(msg, eff, now)

    def _on_currents(self, msg: JointState) -> None:
        arrays = self._joint_arrays(msg)
        if arrays is not None:
            with self._state_lock:
                self._log_effort(msg, arrays[2], self._now_ns())

    def _on_applied(self, msg: CurrentSetpoint) -> None:
        now = self._now_ns()
        with self._state_lock:
            self._applied[(msg.profile_id, int(msg.seq))] = time_to_ns(msg.stamp)
            self._applied_rx_ns = now

    def _on_status(self, msg: DriveGroupStatus) -> None:
        now = self._now_ns()
        claimant = str(msg.owner) if msg.claimed else ""
        with self._state_lock:
            self._status, self._status_rx_ns = msg, now
            if claimant != self._claim_since[0]:
                self._claim_since = (claimant, now)

    def _claim_refusal(self) -> str:
        """Why another client's claim keeps this goal from running ("" = none does), from the
        bridge's typed status of the last 5 s."""
        now = self._now_ns()
        with self._state_lock:
            status, rx, since = self._status, self._status_rx_ns, self._claim_since[1]
        if status is None or now - rx > 5 * NS:
            return ""
        return claim_refusal(status, self.get_fully_qualified_name(), since, now)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        prefix = f"{self.bridge_fqn.lstrip('/')}:"
        for status in msg.status:
            if not status.name.startswith(prefix):
                continue
            values = {kv.key: kv.value for kv in status.values}
            period = _number(values, "sync_period_s")
            if not period and _number(values, "synchronous") == 1.0:   # the player's SYNC watch, µs
                period = _number(values, "sync_period_us") * 1e-6
            counter = _number(values, "missed_setpoints", None)
            if counter is None:
                counter = _number(values, "missed_cycles", None)
            missed = None if counter is None else int(counter)
            now = self._now_ns()
            latched = (status.level == DiagnosticStatus.ERROR
                       and str(status.message).startswith("safe state"))
            with self._state_lock:
                self._sync_period = period if period > 0.0 and np.isfinite(period) else 0.0
                self._bridge_missed = missed
                self._diag_rx_ns = now
                self._bridge_latch = str(status.message) if latched else ""
                self._diag_values = values
                if latched:
                    self._latch_seen_ns = now

    def _state(self) -> tuple[Optional[np.ndarray], Optional[np.ndarray], int]:
        with self._state_lock:
            return self._pos, self._vel, self._state_t

    # --- goal handling ------------------------------------------------------------------------
    def _on_goal(self, goal_request: ExecuteProfile.Goal) -> GoalResponse:
        if self._p("refuse_mode") == "reject":
            # no service call here: the goal callback runs on the executor's only thread, which
            # must stay free to take the answer; the bridge's typed status stands in for get_state
            reason = self._refusal(goal_request, check_busy=True, ask_bridge=False)[1]
            if reason:
                self.get_logger().warn(f"goal rejected: {reason}")
                return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _on_cancel(self, _goal_handle: Any) -> CancelResponse:
        self.get_logger().info("cancel requested: zero current now")
        return CancelResponse.ACCEPT

    def _bridge_state(self) -> Optional[str]:
        """The bridge's lifecycle state label, or None if it does not answer in time."""
        timeout = float(self._p("bridge_timeout"))
        if not self._state_client.wait_for_service(timeout_sec=timeout):
            return None
        future = self._state_client.call_async(GetState.Request())
        done = threading.Event()
        future.add_done_callback(lambda _f: done.set())
        if not done.wait(timeout) or future.result() is None:
            return None
        return future.result().current_state.label

    def _bridge_state_from_status(self) -> Optional[str]:
        """The bridge's state from its typed status of the last 5 s ("active", "inactive",
        "unconfigured", "safe state"), None without one."""
        with self._state_lock:
            status, rx = self._status, self._status_rx_ns
        if status is None or self._now_ns() - rx > 5 * NS:
            return None
        return {DriveGroupStatus.UNCONFIGURED: "unconfigured", DriveGroupStatus.INACTIVE: "inactive",
                DriveGroupStatus.ACTIVE: "active", DriveGroupStatus.SAFE_STATE: "safe state"}.get(
                    int(status.state), "unknown")

    def _busy_reason(self) -> str:
        rid = self._running_id
        what = f"profile {rid!r}" if rid else "a profile"
        return (f"another goal is running ({what}); this executor runs one motion at a time and does not "
                "queue: wait for its result or cancel it")

    def _refusal(self, goal: ExecuteProfile.Goal, check_busy: bool,
                 ask_bridge: bool = True) -> tuple[Optional[Motion], str]:
        """(motion, "") if the goal may run, else (None, reason). ``ask_bridge``: the bridge's
        lifecycle state from its get_state service (blocks up to bridge_timeout s); False: from its
        latest typed status (of the last 5 s; none = not checked here)."""
        if check_busy and self._busy.locked():
            return None, self._busy_reason()
        msg = goal.profile
        try:
            profile = msg_to_profile(msg)
            motion = check_profile(profile, list(msg.joint_names), list(msg.q0), list(msg.qf),
                                   self.config, msg.profile_id)
        except ValueError as exc:
            return None, f"bad profile: {exc}"
        claimed = self._claim_refusal()
        if claimed:
            return None, claimed
        if self._p("require_bridge_active") and not ask_bridge:
            label = self._bridge_state_from_status()
            if label is not None and label != "active":
                return None, (f"bridge '{self._p('bridge_node')}' is '{label}', not 'active'; "
                              "configure and activate it (or fault-reset it) first")
        elif self._p("require_bridge_active"):
            label = self._bridge_state()
            if label is None:
                return None, (f"bridge '{self._p('bridge_node')}' does not answer get_state; "
                              "start it (ff-hwbridge --autostart)")
            if label != "active":
                return None, (f"bridge '{self._p('bridge_node')}' is '{label}', not 'active'; "
                              "configure and activate it (or fault-reset it) first")
        with self._state_lock:
            latch, fresh = self._bridge_latch, self._now_ns() - self._diag_rx_ns < 5 * NS
        if latch and fresh:
            return None, (f"the bridge is in its {latch}; nothing would move: clear it first "
                          f"(ff-ctl fault-reset, or the service {self.bridge_fqn}/fault_reset)")
        pos, vel, t = self._state()
        if pos is not None and self._now_ns() - t > self._p("joint_state_timeout") * NS:
            pos = None
        try:
            check_start_state(pos, vel, motion, self.config)
        except ProfileRejected as exc:
            return None, str(exc)
        return motion, ""

    def _finish(self, goal_handle: Any, success: bool, message: str, motion: Optional[Motion] = None,
                stream: Optional[Stream] = None, start_delay: float = 0.0,
                how: str = "succeed", missed_before: Optional[int] = None) -> ExecuteProfile.Result:
        """End the goal (``how``: succeed / abort / canceled) with a result carrying the final state,
        the model's predicted rest position and the SYNC figures."""
        res = ExecuteProfile.Result(success=success, message=message)
        res.predicted_position = predicted_rest_of(goal_handle.request.profile)
        pos, vel, _ = self._state()
        if motion is not None and pos is not None and vel is not None:
            back = [list(self.config.joint_names).index(n) for n in goal_handle.request.profile.joint_names]
            res.final_position = [float(pos[i]) for i in back]
            res.final_velocity = [float(vel[i]) for i in back]
            res.position_error = [float(pos[i] - motion.qf[i]) for i in back]
        if stream is not None:
            res.setpoints_sent = len(stream.published)
            res.start_delay = float(start_delay)
            stats = self._timing(stream)
            res.switch_error_p50, res.switch_error_p99, res.switch_error_max = (
                stats.p50, stats.p99, stats.max)
            res.sync_period, res.missed_cycles = self._sync_figures(stream, missed_before)
        getattr(goal_handle, how)()
        if success:
            self.get_logger().info(f"goal ended: {message}")
        else:
            self.get_logger().warn(f"goal ended: {message}")
        return res

    def _sync_figures(self, stream: Stream, missed_before: Optional[int]) -> tuple[float, int]:
        """(SYNC period s, setpoints of this stream that missed their cycle).

        The bridge's own counter when it reports one (it counts in SYNCs seen, so SYNC jitter is
        not a miss), from a status sent after the last applied report (waited for at most
        ``DIAG_WAIT`` s); else counted from the applied SYNC instants."""
        end = self._now_ns() + int(DIAG_WAIT * NS)
        while True:
            with self._state_lock:
                fresh = self._diag_rx_ns > self._applied_rx_ns
                applied = dict(self._applied)
                period, counter = self._sync_period, self._bridge_missed
            if fresh or counter is None or missed_before is None or self._now_ns() >= end:
                break
            time.sleep(0.01)
        if missed_before is not None and counter is not None and counter >= missed_before:
            return period, counter - missed_before
        pairs = [(p.setpoint.stamp_ns, applied[(p.setpoint.profile_id, p.setpoint.seq)])
                 for p in stream.published if (p.setpoint.profile_id, p.setpoint.seq) in applied]
        return period, missed_cycles([a for a, _ in pairs], [b for _, b in pairs], period)

    def _timing(self, stream: Stream) -> TimingStats:
        sent = [p.setpoint for p in stream.published]
        with self._state_lock:
            applied = dict(self._applied)
            log = list(self._effort_log or [])
        pairs = [(sp.stamp_ns, applied[(sp.profile_id, sp.seq)]) for sp in sent
                 if sp.switch and (sp.profile_id, sp.seq) in applied]
        if pairs:
            return timing_stats([a for a, _ in pairs], [b for _, b in pairs], "bridge")
        if log:
            est = estimate_applied_times(stream.setpoints, [t for t, _ in log], [e for _, e in log])
            return timing_stats([a for a, _ in est], [b for _, b in est], "estimated")
        return timing_stats([], [], "none")

    # --- the move -----------------------------------------------------------------------------
    async def _execute_in_thread(self, goal_handle: Any) -> ExecuteProfile.Result:
        """Run the goal on its own thread and await it, leaving the executor's threads free
        (see ff_msgs_py.threads: a goal holding an executor thread delayed streaming by seconds)."""
        return await in_thread(self._execute, goal_handle, wake=self._wake, name="ff_executor_goal")

    def _execute(self, goal_handle: Any) -> ExecuteProfile.Result:
        if not self._busy.acquire(blocking=False):
            return self._finish(goal_handle, False, f"refused: {self._busy_reason()}", how="abort")
        # the running goal's id from the moment it holds the executor (its checks may take up to
        # bridge_timeout s), so that a goal refused meanwhile is told which profile runs
        self._running_id = goal_handle.request.profile.profile_id or "(no id)"
        try:
            goal = goal_handle.request
            motion, reason = self._refusal(goal, check_busy=False)
            if motion is None:
                return self._finish(goal_handle, False, f"refused: {reason}", how="abort")
            return self._run(goal_handle, motion)
        finally:
            self._running_id = None
            self._active_stream = None
            self._busy.release()

    def _run(self, goal_handle: Any, motion: Motion) -> ExecuteProfile.Result:
        goal = goal_handle.request
        cfg = self.config
        received = self._now_ns()
        try:
            start = resolve_start(time_to_ns(goal.start_time), received, cfg)
        except ProfileRejected as exc:
            return self._finish(goal_handle, False, f"refused: {exc}", how="abort")
        requested = time_to_ns(goal.start_time) or received
        stream = Stream(build_setpoints(motion, start, cfg.keepalive), cfg.lead_time)
        self._active_stream = stream
        with self._state_lock:
            self._effort_log = deque(maxlen=200_000)
            self._applied = {}
            missed_before = self._bridge_missed
            refused_before = None if self._status is None else int(self._status.refused)
        back = [list(cfg.joint_names).index(n) for n in goal.profile.joint_names]
        lost = {"flag": False}

        def feedback(now: int) -> None:
            pos, vel, t = self._state()
            if stream.start_ns <= now and now - t > self._p("joint_state_timeout") * NS:
                lost["flag"] = True
            fb = ExecuteProfile.Feedback()
            fb.elapsed = max(0.0, (now - stream.start_ns) / NS)
            cur = stream.commanded(now)
            fb.commanded_currents = [float(cur[i]) for i in back]
            if pos is not None and vel is not None:
                fb.measured_positions = [float(pos[i]) for i in back]
                fb.measured_velocities = [float(vel[i]) for i in back]
            goal_handle.publish_feedback(fb)

        def publish(sp: Setpoint) -> None:
            self._pub.publish(setpoint_msg(sp.stamp_ns, sp.currents, sp.seq, sp.profile_id, sp.last))

        def stop_now() -> bool:
            return goal_handle.is_cancel_requested or lost["flag"] or not rclpy.ok(context=self.context)

        period = 1.0 / max(float(self._p("feedback_rate")), 10.0)
        tf_ns = start + int(round(motion.profile.tf * NS))
        self.get_logger().info(f"executing profile {motion.profile_id!r}: {motion.profile.n_steps} "
                               f"steps, {len(stream.setpoints)} setpoints, start in "
                               f"{(start - received) / 1e6:.0f} ms")
        runner = StreamRunner(stream, publish, self._now_ns, time.sleep, stop_now, feedback, period)
        stopped = runner.run(until_ns=tf_ns)
        slip = max((p.published_ns - (p.setpoint.stamp_ns - stream.lead_ns)) / 1e6
                   for p in stream.published)
        self.get_logger().info(f"streamed {len(stream.published)} setpoints; latest publish "
                               f"{slip:.1f} ms after its slot (lead {cfg.lead_time * 1e3:.0f} ms)")
        start_delay = (start - requested) / NS
        if stopped:
            self._wait_settled(feedback, period, timeout=1.0, since_ns=self._now_ns())
            if goal_handle.is_cancel_requested:
                return self._finish(goal_handle, False, "cancelled: zero current sent at once",
                                    motion, stream, start_delay, how="canceled",
                                    missed_before=missed_before)
            return self._finish(goal_handle, False, "aborted: joint states stopped during the move; "
                                "zero current sent", motion, stream, start_delay, how="abort",
                                missed_before=missed_before)
        settled = self._wait_settled(feedback, period, timeout=float(self._p("settle_timeout")),
                                     since_ns=tf_ns)
        pos, _vel, _ = self._state()
        if pos is None:
            return self._finish(goal_handle, False, "no joint state to judge the move",
                                motion, stream, start_delay, how="abort", missed_before=missed_before)
        not_driven = self._not_driven(stream, received, refused_before)
        if not_driven:
            return self._finish(goal_handle, False, f"aborted: {not_driven}; the arm is at "
                                f"{np.round(pos, 6).tolist()} rad", motion, stream, start_delay,
                                how="abort", missed_before=missed_before)
        clipped = self._clipped(received, stream.start_ns, max(tf_ns, self._now_ns()))
        err = pos - motion.qf
        late = stream.late()
        text = (f"{'settled' if settled else 'NOT settled'} at {np.round(pos, 6).tolist()} rad, "
                f"error {np.round(err, 6).tolist()} rad")
        predicted = predicted_rest_of(goal.profile)
        if predicted:
            text += f"; the model predicted {np.round(predicted, 6).tolist()} rad"
        if late:
            text += f"; {len(late)} setpoint(s) reached the bridge after their stamp"
        if clipped:
            return self._finish(goal_handle, False, f"failed: {clipped}; {text}", motion, stream,
                                start_delay, how="abort", missed_before=missed_before)
        return self._finish(goal_handle, True, text, motion, stream, start_delay, how="succeed",
                            missed_before=missed_before)

    def _clipped(self, since_ns: int, start_ns: int, after_ns: int) -> str:
        """Why the move failed by clipping ("" = no drive clipped it): statusword bit 11 counted
        by the bridge for the motion begun after ``since_ns`` (ns), from a status that arrived
        after ``after_ns`` (the move's end; waited for at most ``DIAG_WAIT`` s, else the latest);
        ``start_ns``: the move's start, for the message."""
        end = self._now_ns() + int(DIAG_WAIT * NS)
        while True:
            with self._state_lock:
                values, rx, period = dict(self._diag_values), self._diag_rx_ns, self._sync_period
            if rx >= after_ns or self._now_ns() >= end:
                break
            time.sleep(0.01)
        clips = clipped_joints(values, self.config.joint_names, since_ns)
        return clipping_message(clips, start_ns, period) if clips else ""

    def _not_driven(self, stream: Stream, since_ns: int, refused_before: Optional[int] = None) -> str:
        """Why the bridge did not drive the profile as streamed ("" = it did): it latched its safe
        state during the move, its typed status counts setpoints refused since the move began
        (``refused_before``: its refusal counter then; not the owner's, e.g. a claim or a second
        publisher on the setpoint topic), or it reports applied setpoints but not every current
        change."""
        with self._state_lock:
            latch_ns, latch = self._latch_seen_ns, self._bridge_latch
            applied, applied_rx = dict(self._applied), self._applied_rx_ns
            status = self._status
        if latch_ns >= since_ns:
            return f"the bridge latched its {latch or 'safe state'} during the move"
        if (refused_before is not None and status is not None and status.refused > refused_before
                and str(status.last_refusal).startswith("setpoint")):
            return (f"the bridge refused {status.refused - refused_before} command(s) during the move, "
                    f"the latest: {status.last_refusal}")
        if applied_rx >= since_ns:
            switches = [p.setpoint for p in stream.published if p.setpoint.switch]
            end = self._now_ns() + int(APPLIED_WAIT * NS)
            while True:     # the latest reports may still be on their way from a busy bridge
                got = sum((sp.profile_id, sp.seq) in applied for sp in switches)
                if got == len(switches) or self._now_ns() >= end:
                    break
                time.sleep(0.01)
                with self._state_lock:
                    applied = dict(self._applied)
            if got < len(switches):
                return f"the bridge applied {got} of the profile's {len(switches)} current changes"
        return ""

    def _wait_settled(self, feedback: Callable[[int], None], period: float, timeout: float,
                      since_ns: int = 0) -> bool:
        """Wait until the arm has settled (True) or ``timeout`` s passed (False), sending feedback.
        Only joint states sampled at or after ``since_ns`` (their header stamps: the drives'
        sample instants) count, timed by those stamps: a stream that stopped (a stalled drive
        or bridge) leaves the last state at rest before the move, which says nothing of the
        move's end."""
        det = SettleDetector(self.config.rest_velocity, float(self._p("settle_hold")))
        end = self._now_ns() + int(timeout * NS)
        next_fb = self._now_ns()
        while rclpy.ok(context=self.context):
            now = self._now_ns()
            with self._state_lock:
                vel, sample = self._vel, self._sample_ns
            if vel is not None and sample >= since_ns and det.update(sample, vel):
                return True
            if now >= next_fb:
                feedback(now)
                next_fb = now + int(period * NS)
            if now >= end:
                return False
            time.sleep(min(0.005, period))
        return False

    def emergency_zero(self) -> None:
        """Publish a zero-current setpoint now if a move is running (shutdown path)."""
        stream = self._active_stream
        if stream is not None and not stream.done:
            for sp in stream.cancel(self._now_ns()):
                self._pub.publish(setpoint_msg(sp.stamp_ns, sp.currents, sp.seq, sp.profile_id, True))


def main(argv: Optional[list[str]] = None) -> None:
    """Console script ``ff-executor``: ``ff-executor --ros-args --params-file config/executor.yaml``."""
    # rclpy's own SIGINT handler would shut the context down before we could send a zero
    # current; handle KeyboardInterrupt ourselves instead.
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    # The streaming thread must wake on time while rclpy's executor threads run Python code:
    # a short GIL switch interval bounds that wait (see ff_executor.bringup.timed).
    sys.setswitchinterval(1e-4)
    node = None
    try:
        node = ExecutorNode()
        # one executor thread: no callback waits on another callback (blocking work runs
        # on its own thread, ff_msgs_py.threads), and rclpy's MultiThreadedExecutor costs ~4x
        # the CPU per message (measured 47 % vs 11 % for 200 JointState/s in and out)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        node.get_logger().info(f"{READY_LINE}: action {node.get_fully_qualified_name()}/execute, "
                               f"joints {list(node.config.joint_names)}")
        spin(executor, node.get_logger())
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ValueError, ParameterException) as exc:   # bad parameters: one clear line, no traceback
        print(f"ff_executor: {' '.join(str(exc).split())}", flush=True)
        raise SystemExit(2) from None
    finally:
        shut_down(node, ExecutorNode.emergency_zero)


if __name__ == "__main__":
    main()

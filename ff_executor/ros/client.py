"""A client of the running stack (rclpy in this process): plan, reset the simulated arm, execute.

Used by ``ff-demo``, the end-to-end test and the benchmarks. It calls the planner SERVICE
(``/ff_planner/plan``), the simulated driver's ``/ff_sim_driver/reset``, and the executor ACTION
(``/ff_executor/execute``), and records the simulated arm's ground truth
(``/ff_sim_driver/ground_truth``) and the bridge's joint states during each move.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any, Mapping, Optional, Sequence

import numpy as np
import rclpy
from action_msgs.msg import GoalStatus
from rclpy.action import ActionClient
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from ff_executor.engine import NS
from ff_msgs.action import ExecuteProfile
from ff_msgs.msg import CurrentSetpoint
from ff_msgs.srv import PlanTrajectory
from ff_msgs_py.convert import ns_to_time, time_to_ns
from ff_msgs_py.launch import apply_ros_environment
from ff_msgs_py.spin import spin


class StackCallError(RuntimeError):
    """A service or action of the stack did not answer as expected."""


@dataclass
class Recording:
    """Samples (t in s on the ROS clock, positions rad, velocities rad/s, effort A) of one topic."""

    t: list = field(default_factory=list)
    q: list = field(default_factory=list)
    qd: list = field(default_factory=list)
    effort: list = field(default_factory=list)

    def arrays(self, t0: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(t − t0 s, q rad, qd rad/s, effort A) as arrays, one row per sample."""
        return (np.asarray(self.t) - t0, np.asarray(self.q), np.asarray(self.qd),
                np.asarray(self.effort))


@dataclass
class MoveOutcome:
    """What one execution gave: the action result, feedback count, and the recordings."""

    status: int
    result: Any                    # ExecuteProfile.Result
    feedback: int
    feedback_period_max: float     # s, longest gap between feedback messages (as received here)
    feedback_rate: float           # Hz, messages / time between the first and the last
    start_time: float              # s, ROS clock, when the first setpoint took effect (planned)
    truth: Recording
    joints: Recording
    rest_truth: Optional[np.ndarray]   # rad, ground-truth position once settled
    switch_delays: list = field(default_factory=list)   # s, bridge-applied − stamp per switch
    profile_start: Optional[float] = None     # s, ROS clock: stamp of the move's first setpoint

    @property
    def switch_spread(self) -> float:
        """s, max − min of the switch delays: the relative timing error between switches
        (a common delay of the whole profile does not move the arm's final position)."""
        return float(np.ptp(self.switch_delays)) if self.switch_delays else float("nan")

    @property
    def succeeded(self) -> bool:
        """True if the goal succeeded and its result says so."""
        return self.status == GoalStatus.STATUS_SUCCEEDED and bool(self.result.success)


class SafeActionClient(ActionClient):
    """An rclpy ActionClient whose responses cannot overtake their requests.

    rclpy's ActionClient registers a request's future only after sending it; a response taken
    by another executor thread in between is dropped ("Ignoring unexpected goal response") and
    the caller waits forever. One lock serialises the two paths.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._ff_lock = threading.RLock()
        super().__init__(*args, **kwargs)

    def send_goal_async(self, *args: Any, **kwargs: Any) -> Any:
        with self._ff_lock:
            return super().send_goal_async(*args, **kwargs)

    def _cancel_goal_async(self, *args: Any, **kwargs: Any) -> Any:
        with self._ff_lock:
            return super()._cancel_goal_async(*args, **kwargs)

    def _get_result_async(self, *args: Any, **kwargs: Any) -> Any:
        with self._ff_lock:
            return super()._get_result_async(*args, **kwargs)

    async def execute(self, taken_data: Any) -> Any:
        with self._ff_lock:   # wait until a request in flight has registered its future
            pass
        return await super().execute(taken_data)


class StackClient:
    """rclpy node + executor thread in this process; apply the stack's env before creating it."""

    def __init__(self, env: Mapping[str, str], name: str = "ff_client", namespace: str = "") -> None:
        """``namespace``: the stack's (``ff-bringup --namespace``, e.g. "arm_a"); "" = root."""
        apply_ros_environment(env)
        ns = f"/{namespace.strip('/')}" if namespace.strip("/") else ""
        self.ns = ns
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        self.node = Node(name, context=self.ctx)
        self.plan_client = self.node.create_client(PlanTrajectory, f"{ns}/ff_planner/plan")
        self.reset_client = self.node.create_client(Trigger, f"{ns}/ff_sim_driver/reset")
        self.action = SafeActionClient(self.node, ExecuteProfile, f"{ns}/ff_executor/execute")
        qos = QoSProfile(depth=200, reliability=ReliabilityPolicy.BEST_EFFORT)
        self._lock = threading.Lock()
        self._truth: Optional[Recording] = None
        self._joints: Optional[Recording] = None
        self.last_truth: Optional[tuple[float, np.ndarray, np.ndarray]] = None   # (t s, q rad, qd rad/s)
        # monotonic s of the latest sample received from the simulated arm and from the bridge
        self._heard: dict[str, float] = {}
        self.node.create_subscription(JointState, f"{ns}/ff_sim_driver/ground_truth",
                                      lambda m: self._on_js(m, "truth"), qos)
        # the bridge's samples with effort = motor current A (its joint_states carry N·m)
        self.node.create_subscription(JointState, f"{ns}/ff_hwbridge/motor_currents",
                                      lambda m: self._on_js(m, "joints"), qos)
        self._stamps: dict[tuple[str, int], tuple[int, tuple[float, ...]]] = {}
        self._applied: dict[tuple[str, int], int] = {}

        def on_setpoint(m: CurrentSetpoint) -> None:
            with self._lock:
                self._stamps[(m.profile_id, m.seq)] = (time_to_ns(m.stamp), tuple(m.currents))

        def on_applied(m: CurrentSetpoint) -> None:
            with self._lock:
                self._applied[(m.profile_id, m.seq)] = time_to_ns(m.stamp)

        rel = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(CurrentSetpoint, f"{ns}/ff_hwbridge/setpoints", on_setpoint, rel)
        self.node.create_subscription(CurrentSetpoint, f"{ns}/ff_hwbridge/applied", on_applied, rel)
        self.executor = MultiThreadedExecutor(num_threads=2, context=self.ctx)
        self.executor.add_node(self.node)
        self._spin = threading.Thread(target=spin, args=(self.executor,), daemon=True)
        self._spin.start()

    def close(self) -> None:
        """Stop the executor thread, destroy the node and shut the context down."""
        self.executor.shutdown()
        # the spin thread must leave its wait set before the node's entities are destroyed
        self._spin.join(timeout=5.0)
        self.node.destroy_node()
        if self.ctx.ok():
            rclpy.shutdown(context=self.ctx)

    def __enter__(self) -> "StackClient":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def now(self) -> float:
        """This node's ROS clock (s)."""
        return self.node.get_clock().now().nanoseconds / NS

    def _on_js(self, msg: JointState, which: str) -> None:
        # the publisher's stamp (when the sample was taken); the receive time only if unstamped
        stamp = msg.header.stamp.sec * NS + msg.header.stamp.nanosec
        t = stamp / NS if stamp else self.now()
        q = list(msg.position)
        qd = list(msg.velocity) if len(msg.velocity) == len(q) else [0.0] * len(q)
        eff = list(msg.effort) if len(msg.effort) == len(q) else [float("nan")] * len(q)
        with self._lock:
            self._heard[which] = time.monotonic()
            if which == "truth":
                self.last_truth = (t, np.array(q), np.array(qd))
            rec = self._truth if which == "truth" else self._joints
            if rec is not None:
                rec.t.append(t)
                rec.q.append(q)
                rec.qd.append(qd)
                rec.effort.append(eff)

    @staticmethod
    def _wait(future: Any, timeout: float, what: str) -> Any:
        end = time.monotonic() + timeout
        while not future.done() and time.monotonic() < end:
            time.sleep(0.005)
        if not future.done():
            raise StackCallError(f"{what}: no answer within {timeout:.0f} s")
        return future.result()

    def wait_for_streams(self, timeout: float = 15.0, since: float = 0.0) -> None:
        """Wait until both recorded streams (the simulated arm's ground truth and the bridge's
        motor currents) have delivered a sample received after ``since`` (monotonic s).

        Each comes from another process, whose publishers this node discovers on its own
        schedule: a service or action answering says nothing about them, and on a loaded machine
        the bridge's may match seconds later (a move recorded with no sample at all)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self._lock:
                heard = dict(self._heard)
            if all(heard.get(k, -1.0) > since for k in ("truth", "joints")):
                return
            time.sleep(0.01)
        missing = [topic for k, topic in (("truth", "/ff_sim_driver/ground_truth"),
                                          ("joints", "/ff_hwbridge/motor_currents"))
                   if heard.get(k, -1.0) <= since]
        raise StackCallError(f"no sample on {', '.join(missing)} within {timeout:.0f} s")

    def _first_stamp(self, timeout: float, result: Optional[Any] = None) -> Optional[float]:
        """Stamp (s, ROS clock) of step 0 of the goal being executed, once its setpoint is seen;
        None when ``result`` (the goal's result future) completes first (the goal ended without a
        step, e.g. aborted at once: its result says why)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self._lock:
                first = next((ns for (_, seq), (ns, _) in self._stamps.items() if seq == 0), None)
            if first is not None:
                return first / NS
            if result is not None and result.done():
                return None
            time.sleep(0.005)
        raise StackCallError(f"the executor published no setpoint within {timeout:.0f} s")

    # --- calls --------------------------------------------------------------------------------
    def plan(self, request: PlanTrajectory.Request, timeout: float = 120.0) -> PlanTrajectory.Response:
        """Call /ff_planner/plan with a PlanTrajectory.Request; returns the response."""
        if not self.plan_client.wait_for_service(timeout_sec=15.0):
            raise StackCallError("the planner service /ff_planner/plan is not available")
        return self._wait(self.plan_client.call_async(request), timeout, "plan")

    def fault_reset(self, timeout: float = 10.0) -> str:
        """Clear a latched safe state of the bridge (its ``~/fault_reset``, std_srvs/Trigger; open
        while no client holds a claim); returns its message, StackCallError when refused."""
        cli = self.node.create_client(Trigger, f"{self.ns}/ff_hwbridge/fault_reset")
        try:
            if not cli.wait_for_service(timeout_sec=timeout):
                raise StackCallError(f"the bridge's {self.ns}/ff_hwbridge/fault_reset is not available")
            res = self._wait(cli.call_async(Trigger.Request()), timeout, "fault reset")
        finally:
            self.node.destroy_client(cli)
        if not res.success:
            raise StackCallError(f"fault reset refused: {res.message}")
        return str(res.message)

    def reset_arm(self, q0: Sequence[float] = (0.0,), timeout: float = 10.0,
                  rest_velocity: float = 1e-6) -> None:
        """Put the simulated arm back (sim driver's ~/reset) and wait until it reads q0 at rest."""
        if not self.reset_client.wait_for_service(timeout_sec=10.0):
            raise StackCallError("the simulated driver's /ff_sim_driver/reset is not available")
        res = self._wait(self.reset_client.call_async(Trigger.Request()), timeout, "reset")
        if not res.success:
            raise StackCallError(f"reset refused: {res.message}")
        end = time.monotonic() + timeout
        target = np.asarray(q0, dtype=float)
        while time.monotonic() < end:
            with self._lock:
                lt = self.last_truth
            if lt is not None and lt[0] > self.now() - 0.5 and np.allclose(lt[1], target, atol=1e-6) \
                    and np.all(np.abs(lt[2]) <= rest_velocity):
                seen = time.monotonic()
                time.sleep(0.2)   # let the bridge's joint states catch up too
                # and at least one of them received after the arm was seen at rest
                self.wait_for_streams(max(1.0, end - time.monotonic()), since=seen)
                return
            time.sleep(0.02)
        raise StackCallError(f"the simulated arm did not come back to {target.tolist()} at rest")

    def execute(self, profile_msg: Any, timeout: float = 30.0,
                cancel_into_move: Optional[float] = None,
                start_time: Optional[float] = None) -> MoveOutcome:
        """Send an ExecuteProfile goal and record ground truth and joint states until the result.

        start_time (s, ROS clock): when step 0 must start (the goal's ``start_time``); None: as
        soon as the executor can.

        cancel_into_move (s): cancel the goal this long after step 0's stamp, as the executor
        published it (``lead_time`` ahead of the step), wherever the executor put the start;
        None: no cancel."""
        if not self.action.wait_for_server(timeout_sec=15.0):
            raise StackCallError("the executor action /ff_executor/execute is not available")
        self.wait_for_streams()
        fb_times: list[float] = []
        with self._lock:
            self._truth, self._joints = Recording(), Recording()
            self._stamps, self._applied = {}, {}
        t_goal = self.now()
        goal = ExecuteProfile.Goal(profile=profile_msg)
        if start_time is not None:
            goal.start_time = ns_to_time(int(round(start_time * NS)))
        handle = self._wait(self.action.send_goal_async(
            goal, feedback_callback=lambda _m: fb_times.append(time.monotonic())), 15.0, "send goal")
        if not handle.accepted:
            raise StackCallError("the executor rejected the goal (see its log)")
        res_future = handle.get_result_async()
        if cancel_into_move is not None:
            start = self._first_stamp(15.0, res_future)
            if start is not None:       # None: the goal has already ended (its result says how)
                time.sleep(max(0.0, start + cancel_into_move - self.now()))
                self._wait(handle.cancel_goal_async(), 10.0, "cancel")
        res = self._wait(res_future, timeout, "execute")
        t_result = self.now()
        end = time.monotonic() + 2.0        # a ground-truth sample taken after the result, at rest
        while time.monotonic() < end:
            with self._lock:
                lt = self.last_truth
            if lt is not None and lt[0] >= t_result and np.all(np.abs(lt[2]) <= 1e-3):
                break
            time.sleep(0.01)
        with self._lock:
            truth, joints = self._truth, self._joints
            self._truth = self._joints = None
            lt = self.last_truth
            delays, prev = [], None
            first = min((v[0] for v in self._stamps.values()), default=None)
            for key in sorted(self._stamps, key=lambda k: self._stamps[k][0]):
                stamp, cur = self._stamps[key]
                if cur != prev and key in self._applied:
                    delays.append((self._applied[key] - stamp) / NS)
                prev = cur
        gaps = np.diff(fb_times) if len(fb_times) > 1 else np.array([np.inf])
        rate = (len(fb_times) - 1) / (fb_times[-1] - fb_times[0]) if len(fb_times) > 1 else 0.0
        rest = lt[1] if lt is not None else None
        return MoveOutcome(res.status, res.result, len(fb_times), float(gaps.max()), float(rate),
                           t_goal, truth, joints, rest, delays,
                           None if first is None else first / NS)

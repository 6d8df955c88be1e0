"""ROS 2 node ``ff_planner``: serves ``~/plan`` (ff_msgs/srv/PlanTrajectory), the action
``~/plan_long`` (ff_msgs/action/PlanMotion: the same request, progress feedback, cancel) and
``/diagnostics``.

A thin adapter around :class:`ff_planner.service.planner_service.PlannerService` (all logic there, no ROS).
Parameters come from YAML (``--ros-args --params-file config/planner.yaml``); see that file for the
names. Service calls run in a reentrant callback group on a multi-threaded executor and wait on a
pool of worker processes, so a long 2-DOF plan never blocks 1-DOF requests; diagnostics run in
their own group. The action takes one goal at a time (a second is rejected while one runs, the
reason in the node's log) and shares the workers with the service; a cancel kills the goal's
worker (replaced at once) and the goal ends canceled within ~0.1 s.

Console script: ``ff-planner-node`` (= ``ff_planner.ros.planner_node:main``).
"""
from __future__ import annotations

import json
import multiprocessing
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any, Optional

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from ff_msgs.action import PlanMotion
from ff_msgs.srv import PlanTrajectory
from ff_msgs_py.configs import config_dir, node_parameters
from ff_msgs_py.convert import error_response
from ff_msgs_py.threads import in_thread
from ff_msgs_py.spin import spin
from ff_planner.armplan.requests import (PARAM_PREFIX, ArmRequest, RegisteredArm, is_urdf_model,
                                         plan_registered, registry_from_parameters)
from ff_planner.library.warm import PlanFn
from ff_planner.model.profile import PlanResult
from ff_planner.optimize.planner import plan
from ff_planner.ros.messages import feedback_from_progress, fields_from_msg, fill_response
from ff_planner.service.planner_service import (CANCELED, LIMIT_NAMES, PlannerService, RequestFields,
                                                ServiceConfigError, config_from_mapping)

FEEDBACK_PERIOD = 0.2   # s between PlanMotion feedback messages
ARM_WORKER_SLACK = 60.0  # s past a urdf:NAME request's budget: the worker's start-up (imports,
#                          compiled kernels from their cache, the arm's URDF and fit) and certificate

NODE_ONLY = ("diagnostics_period", "executor_threads")
#: the shipped parameter file whose values are the node's defaults (the one source: a node started
#: with no file, or with a file that leaves a key out, has that key as the shipped YAML gives it)
SHIPPED = ("planner.yaml", "ff_planner")
#: node-only parameters the shipped YAML leaves out, with their defaults
NODE_DEFAULTS: dict[str, Any] = {"executor_threads": 0}
ROS_BUILTIN = ("use_sim_time", "start_type_description_service")  # declared by every rclpy node
#: name: (description with units, (from, to) range or None) of config/planner.yaml's parameters.
#: All are read once, at start (read_only); types stay as the YAML gives them (dynamic typing),
#: the service's configuration converts and checks them.
PARAMETERS: dict[str, tuple[str, Optional[tuple[float, float]]]] = {
    "default_model": ("model id used when a request leaves `model` empty: arm1dof | scara2", None),
    "default_objective": ("objective used when a request leaves `objective` empty: robust-box "
                          "(least worst rest error over the friction box) | robust-derivative | "
                          "robust-sampled | time-optimal | energy-optimal", None),
    "current_quantum": ("A, round every plan's currents to this grid, the drive's setpoint unit "
                        "(EPOS4: nominal current / 1000, e.g. 0.003); rest position and "
                        "certificate are for the rounded profile; 0 = none", (0.0, 1.0)),
    "default_starts": ("multistart count when a request says 0", (1, 10_000_000)),
    "default_time_budget": ("s, wall-clock planning budget when a request says 0", (0.0, 86400.0)),
    "max_time_budget": ("s; requests asking for more are refused", (0.0, 86400.0)),
    "max_steps": ("current steps per joint; larger requests are refused", (1, 100_000)),
    "max_starts": ("multistart starts per request, at most", (1, 10_000_000)),
    "max_move_time": ("s, longest move accepted", (0.0, 86400.0)),
    "coast": ("s, zero-current coast at the end of every move", (0.0, 60.0)),
    "tol": ("robustness tolerance: |dq(tf)/dp| (rad per parameter unit) and |q(tf) - qf| (rad)", (0.0, 1.0)),
    "library_path": ("motion library (SQLite) file, shared with ff-library build; '' = none", None),
    "use_library": ("look requests up in the motion library and store new plans there", None),
    "warm_max_distance": ("rad (move time weighted by time_weight): re-optimise from a stored neighbour "
                          "this close", (0.0, 1e6)),
    "time_weight": ("rad per s of move-time difference in the neighbour distance", (0.0, 1e6)),
    "workers": ("planner worker processes (scara2 plans use at most workers - 1)", (1, 1024)),
    "max_pending": ("requests waiting or running; more are refused at once", (1, 1_000_000)),
    "max_pending_long": ("scara2 requests waiting or running; 0 = max_pending // 2", (0, 1_000_000)),
    "grace": ("s past a request's time budget before its worker is killed", (0.0, 3600.0)),
    "motion_dir": ("folder: write every plan as an ff-motion/1 file there; '' = off", None),
    "warmup": ("plan a small task in each worker at start (loads the compiled kernels)", None),
    "switch_grid": ("s, put switch times on this grid when a request says 0 (the drives' SYNC period; "
                    "default 0.001 = 1 ms); 0 = no grid. Applied by the robust 1-DOF planners "
                    "(robust-derivative, robust-sampled, robust-box)", (0.0, 1.0)),
    "drive_config": ("the bridge's config file (config/bridge_*.yaml): every plan drive-exact for "
                     "its drive: currents on its setpoint unit, switch times on its sync_period "
                     "(replaces switch_grid), certificate on that profile; '' = none", None),
    "diagnostics_period": ("s between /diagnostics messages; 0 = off", (0.0, 3600.0)),
    "executor_threads": ("rclpy executor threads; 0 = max_pending + 4", (0, 100_000)),
}


#: the shipped arms (config/planner.yaml's arms.NAME.urdf / arms.NAME.cell)
SHIPPED_ARMS = ("arm1dof", "scara2", "arm3h", "vertical2")
PARAMETERS.update({f"{PARAM_PREFIX}{arm}.{half}": (
    f"{half} file of the arm served as model id urdf:{arm} (docs/arms.md); relative paths also "
    "from the suite's config folder", None) for arm in SHIPPED_ARMS for half in ("urdf", "cell")})


def descriptor(name: str, value: Any = None) -> ParameterDescriptor:
    """ParameterDescriptor of planner parameter ``name`` (``<model>.preset`` and
    ``<model>.params.<key>`` included); read-only: the node reads its parameters at start."""
    text, rng = PARAMETERS.get(name, ("", None))
    parts = name.split(".")
    if not text and len(parts) == 2 and parts[1] == "preset":
        text = f"paper parameter set of model {parts[0]} (table1 | table2 | table3)"
    elif not text and len(parts) == 2 and parts[1] in LIMIT_NAMES:
        text = (f"{'rad/s' if parts[1] == 'velocity_max' else 'rad'} per joint: the cell's "
                f"{parts[1]} for {parts[0]} requests that give none (held along the whole motion "
                f"at every point of the friction box)")
    elif not text and len(parts) == 3 and parts[0] == "arms" and parts[2] in ("urdf", "cell"):
        text = (f"{parts[2]} file of the arm served as model id urdf:{parts[1]} (docs/arms.md); "
                "relative paths also from the suite's config folder")
    elif not text and len(parts) == 3 and parts[1] == "params":
        text = f"SI units: override of model {parts[0]}'s parameter {parts[2]} (ff_planner/model/params.py)"
    d = ParameterDescriptor(name=name, description=(text + " (read at start)").lstrip(), read_only=True,
                            dynamic_typing=True)
    if rng is not None and isinstance(value, int) and not isinstance(value, bool):
        d.integer_range = [IntegerRange(from_value=int(rng[0]), to_value=int(rng[1]), step=0)]
    elif rng is not None and isinstance(value, float):
        d.floating_point_range = [FloatingPointRange(from_value=float(rng[0]), to_value=float(rng[1]), step=0.0)]
    return d


def _flatten(values: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested maps of a parameter file as ROS names them: {"arms": {"a": {"urdf": f}}} ->
    {"arms.a.urdf": f}."""
    out: dict[str, Any] = {}
    for key, value in values.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def shipped_defaults() -> dict[str, Any]:
    """The ``ros__parameters`` of the shipped config/planner.yaml: the node's defaults (nested
    maps flattened to dotted names, as ROS reads them)."""
    return _flatten(node_parameters(*SHIPPED))


def resolve_config_path(text: str) -> Path:
    """A configured file: absolute, or relative to the working folder, else to the suite's
    config folder."""
    p = Path(text).expanduser()
    if p.is_absolute() or p.is_file():
        return p
    return config_dir() / p


def parameters_markdown() -> str:
    """The Markdown table of the planner's parameters: every key of the shipped YAML, its value
    there (the default), then the node-only ones, each with its description (docs/parameters.md,
    between its markers)."""
    rows = ["| name | default | range | description |", "|---|---|---|---|"]
    for name, default in {**shipped_defaults(), **NODE_DEFAULTS}.items():
        if name.startswith(PARAM_PREFIX):      # the registered arms: docs/arms.md
            continue
        rng = PARAMETERS.get(name, ("", None))[1]
        text = descriptor(name, default).description.replace(" (read at start)", "")
        rows.append(f"| `{name}` | `{json.dumps(default)}` | {f'{rng[0]:g} .. {rng[1]:g}' if rng else ''} | "
                    f"{text.replace('|', '/')} |")
    return "\n".join(rows) + "\n"


def _tf_of(result: Any) -> str:
    """The move time (s) a plan chose, for logs."""
    return f"{result.profile.tf:g} s" if result.profile is not None else "none"


class PlannerNode(Node):
    """The ``ff_planner`` node. Raises ServiceConfigError on a bad configuration.

    ``plan_fn``: the planner the workers run (default: the facade ``ff_planner.optimize.planner.plan``).
    """

    def __init__(self, plan_fn: PlanFn = plan, **kwargs: Any) -> None:
        super().__init__("ff_planner", **kwargs)
        # every key of the shipped config/planner.yaml with its value there as the default, and
        # every further parameter a given file sets (<model>.params.<key>, limits;
        # config_from_mapping refuses unknown names), each with its descriptor
        names = {**NODE_DEFAULTS, **shipped_defaults()}
        for name, param in self._parameter_overrides.items():
            if name not in ROS_BUILTIN and not name.startswith("qos_overrides"):
                names.setdefault(name, param.value)
        for name, default in sorted(names.items()):
            self.declare_parameter(name, default, descriptor(name, default))
        values = {name: p.value for name, p in self._parameters.items()
                  if name not in ROS_BUILTIN and not name.startswith("qos_overrides")}
        self.diagnostics_period = float(values.pop("diagnostics_period", 1.0))
        self.executor_threads = int(values.pop("executor_threads", 0))
        arm_values = {k: values.pop(k) for k in list(values) if k.startswith(PARAM_PREFIX)}
        try:
            self.arms: dict[str, RegisteredArm] = registry_from_parameters(arm_values, resolve_config_path)
        except ValueError as exc:
            raise ServiceConfigError(str(exc)) from None
        self._arm_pool: Optional[Any] = None           # one worker process for urdf:NAME plans
        self._arm_lock = threading.Lock()
        config = config_from_mapping(values)
        if self.executor_threads <= 0:
            self.executor_threads = config.max_pending + 4
        self.service = PlannerService(config, plan_fn=plan_fn, log=lambda m: self.get_logger().warning(m))
        self.get_logger().info(
            f"starting {config.workers} planner workers (library: {config.library_path or 'off'}, "
            f"planner: {self.service.planner_name}; arms from a URDF: "
            f"{', '.join('urdf:' + n for n in sorted(self.arms)) or 'none'})")
        self.service.start()
        # a deep request queue: a burst of requests waits in DDS instead of being dropped (the
        # default depth of 10 loses requests); admission control then answers or refuses each one
        qos = QoSProfile(depth=max(256, 8 * config.max_pending), reliability=ReliabilityPolicy.RELIABLE)
        self._wake = self.create_guard_condition(lambda: None)   # resumes awaited work (ff_msgs_py.threads)
        self._srv = self.create_service(PlanTrajectory, "~/plan", self._on_plan, qos_profile=qos,
                                        callback_group=ReentrantCallbackGroup())
        self._goal_lock = threading.Lock()
        self._goal_busy: Optional[tuple[str, float]] = None    # (goal id, time.monotonic() accepted)
        self._action = ActionServer(self, PlanMotion, "~/plan_long", execute_callback=self._on_plan_long,
                                    goal_callback=self._on_goal, cancel_callback=self._on_cancel,
                                    callback_group=ReentrantCallbackGroup())
        self._diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        if self.diagnostics_period > 0:
            self.create_timer(self.diagnostics_period, self._publish_diagnostics,
                              callback_group=MutuallyExclusiveCallbackGroup())

    async def _on_plan(self, req: PlanTrajectory.Request, res: PlanTrajectory.Response) -> PlanTrajectory.Response:
        """Service ~/plan: the (blocking) handling runs on its own thread (ff_msgs_py.threads)."""

        return await in_thread(self._plan_blocking, req, res, wake=self._wake, name="ff_plan_request")

    def _plan_blocking(self, req: PlanTrajectory.Request, res: PlanTrajectory.Response) -> PlanTrajectory.Response:
        try:
            fields = fields_from_msg(req)
            result = self._plan_urdf(fields) if is_urdf_model(fields.model) else self.service.handle_fields(fields)
            self._encode(result, res)
            self._log_result("plan", req, result)
        except Exception as exc:  # noqa: BLE001 - never die on a request
            self.get_logger().error(f"request failed: {exc!r}")
            error_response(res, "INTERNAL_ERROR", f"planner node error: {exc}")
        return res

    def _plan_urdf(self, fields: RequestFields) -> PlanResult:
        """A ``urdf:NAME`` request: planned for the registered arm in the node's arm worker
        process (``ff_planner.armplan.requests``); with a ``tolerance`` (rad) the fastest move
        time ≤ ``move_time_max`` (s) certified within it (``ff_planner.armplan.fastest``; none
        meets it: the least-worst plan, not a success, NO_ROBUST_PLAN). Killed and answered
        TIME_BUDGET_EXHAUSTED when it runs past its budget plus ARM_WORKER_SLACK s (its start-up
        included)."""
        c = self.service.config
        unsupported = tuple(name for name, given in (
            ("uncertain", fields.uncertain), ("override_names", fields.override_names),
            ("box_names", fields.box_names), ("coast_max", fields.coast_max),
            ("switch_grid", fields.switch_grid), ("position_min", fields.position_min),
            ("position_max", fields.position_max), ("velocity_max", fields.velocity_max)) if given)
        req = ArmRequest(model=fields.model, q0=[float(x) for x in fields.q0],
                         qf=[float(x) for x in fields.qf], move_time=float(fields.move_time),
                         objective=str(fields.objective), steps=int(fields.steps),
                         seed=int(fields.seed), time_budget=float(fields.time_budget),
                         unsupported=unsupported, tolerance=float(fields.tolerance),
                         move_time_max=float(fields.move_time_max))
        kwargs = dict(default_time_budget=c.default_time_budget, max_time_budget=c.max_time_budget,
                      max_steps=c.max_steps, max_move_time=c.max_move_time, coast=c.coast)
        budget = min(float(fields.time_budget) or c.default_time_budget, c.max_time_budget)
        with self._arm_lock:          # one arm plan at a time (one worker process)
            if self._arm_pool is None:
                # the worker ignores SIGINT: the node stops it (terminate) when it shuts down
                self._arm_pool = multiprocessing.get_context("spawn").Pool(
                    1, initializer=signal.signal, initargs=(signal.SIGINT, signal.SIG_IGN))
            job = self._arm_pool.apply_async(plan_registered, (req, self.arms), kwargs)
            try:
                return job.get(timeout=budget + ARM_WORKER_SLACK)
            except multiprocessing.TimeoutError:
                self._arm_pool.terminate()
                self._arm_pool = None
                return PlanResult(success=False, message=f"{fields.model}: no answer within "
                                  f"{budget + ARM_WORKER_SLACK:g} s (its worker was stopped)",
                                  profile=None, model=fields.model, params=None,
                                  q0=np.asarray(req.q0, float), qf=np.asarray(req.qf, float),
                                  uncertain=[], objective="robust-box",
                                  error_code="TIME_BUDGET_EXHAUSTED")

    def _encode(self, result: Any, res: Any) -> None:
        try:
            fill_response(result, res)
        except Exception as exc:  # noqa: BLE001 - e.g. a profile that cannot become a message
            error_response(res, "INTERNAL_ERROR", f"could not encode the plan: {exc}")

    def _log_result(self, what: str, req: Any, result: Any) -> None:
        extra = result.extra or {}
        # the service's answers carry their latency; a urdf:NAME plan its planning time (s)
        latency = float(extra.get("latency", getattr(result, "solve_time", 0.0) or 0.0))
        self.get_logger().info(
            f"{what} {req.model or '-'} {list(req.q0)} -> {list(req.qf)} "
            + (f"tf={req.move_time:g}" if not req.tolerance else
               f"tolerance={req.tolerance:g} rad, tf chosen {_tf_of(result)}") + ": "
            f"{result.error_code} ({extra.get('source', '?')}, {1e3 * latency:.1f} ms)"
            + ("" if result.success else f": {result.message}"))

    # --- the ~/plan_long action ---------------------------------------------------------------
    def _on_goal(self, goal: PlanMotion.Goal) -> GoalResponse:
        """One goal at a time: a second one is rejected while one runs (reason logged)."""
        with self._goal_lock:
            if self._goal_busy is not None:
                gid, since = self._goal_busy
                self.get_logger().warning(
                    f"plan_long goal rejected: busy with goal {gid} for {time.monotonic() - since:.1f} s "
                    f"(one goal at a time); wait for it, cancel it, or call the ~/plan service")
                return GoalResponse.REJECT
            self._goal_busy = ("?", time.monotonic())
        return GoalResponse.ACCEPT

    def _on_cancel(self, _goal_handle: Any) -> CancelResponse:
        return CancelResponse.ACCEPT

    async def _on_plan_long(self, goal_handle: Any) -> PlanMotion.Result:
        """Action ~/plan_long: plans on its own thread, with feedback and cancel."""
        try:
            return await in_thread(self._plan_long_blocking, goal_handle, wake=self._wake, name="ff_plan_goal")
        finally:
            with self._goal_lock:
                self._goal_busy = None

    def _plan_long_blocking(self, goal_handle: Any) -> PlanMotion.Result:
        gid = bytes(goal_handle.goal_id.uuid).hex()[:8]
        t0 = time.monotonic()
        with self._goal_lock:
            self._goal_busy = (gid, t0)
        goal = goal_handle.request
        res = PlanMotion.Result()
        cancel = threading.Event()
        latest: dict[str, Any] = {}
        stage = ["accepted"]
        lock = threading.Lock()

        def progress(report: dict) -> None:
            with lock:
                if report.get("stage"):
                    stage[0] = str(report["stage"])
                latest.clear()
                latest.update(report)

        box: list[Any] = []
        fields = fields_from_msg(goal)
        if is_urdf_model(fields.model):
            work = lambda: box.append(self._plan_urdf(fields))  # noqa: E731
        else:
            work = lambda: box.append(self.service.handle_fields(fields, progress, cancel))  # noqa: E731
        worker = threading.Thread(target=work, name="ff_plan_goal_work", daemon=True)
        self.get_logger().info(f"plan_long goal {gid}: {goal.model or '-'} {list(goal.q0)} -> {list(goal.qf)} "
                               f"tf={goal.move_time:g} {goal.objective or self.service.config.default_objective}")
        worker.start()
        total = int(goal.starts)
        steps = int(goal.steps) or (2 + len(goal.uncertain) if len(goal.uncertain) else 0)
        while worker.is_alive():
            worker.join(FEEDBACK_PERIOD)
            if goal_handle.is_cancel_requested and not cancel.is_set():
                self.get_logger().info(f"plan_long goal {gid}: cancel requested")
                cancel.set()
            if worker.is_alive() and goal_handle.is_active:
                with lock:
                    fb = feedback_from_progress(PlanMotion.Feedback(), latest, stage=stage[0],
                                                starts_total=total, steps=steps, elapsed=time.monotonic() - t0)
                goal_handle.publish_feedback(fb)
        if not box:
            error_response(res, "INTERNAL_ERROR", "planner node error: the plan ended without an answer")
            goal_handle.abort()
            return res
        result = box[0]
        self._encode(result, res)
        self._log_result(f"plan_long goal {gid}", goal, result)
        if (result.extra or {}).get(CANCELED) or (cancel.is_set() and not result.success):
            goal_handle.canceled()
        elif result.success:
            goal_handle.succeed()
        else:
            goal_handle.abort()
        return res

    def _publish_diagnostics(self) -> None:
        stats = self.service.stats()
        st = DiagnosticStatus(name="ff_planner: planning", hardware_id="ff_planner")
        overloaded = stats.get("pending", 0) >= self.service.config.max_pending
        st.level = DiagnosticStatus.WARN if overloaded else DiagnosticStatus.OK
        st.message = (f"{stats.get('requests', 0)} requests, {stats.get('pending', 0)} in progress"
                      + (" (overloaded)" if overloaded else ""))
        st.values = [KeyValue(key=k, value=f"{v:.6g}" if isinstance(v, float) else str(v))
                     for k, v in sorted(stats.items())]
        msg = DiagnosticArray(status=[st])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._diag.publish(msg)

    def destroy_node(self) -> None:
        if self._arm_pool is not None:
            self._arm_pool.terminate()
            self._arm_pool = None
        self.service.close()
        super().destroy_node()


def main(argv: Optional[list[str]] = None, plan_fn: PlanFn = plan) -> int:
    """Console script ``ff-planner-node``; ``plan_fn`` replaces the planner (a module-level function)."""
    rclpy.init(args=argv if argv is not None else sys.argv)
    node: Optional[PlannerNode] = None
    code = 0
    try:
        try:
            node = PlannerNode(plan_fn=plan_fn)
        except ServiceConfigError as exc:
            print(f"ff_planner: bad configuration: {exc}", file=sys.stderr)
            return 2
        executor = MultiThreadedExecutor(num_threads=node.executor_threads)
        executor.add_node(node)
        node.get_logger().info("ff_planner ready: service ~/plan, action ~/plan_long")
        spin(executor, node.get_logger())
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())

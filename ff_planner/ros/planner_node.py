"""ROS 2 node ``ff_planner``: serves ``~/plan`` (ff_msgs/srv/PlanTrajectory) and ``/diagnostics``.

A thin adapter around :class:`ff_planner.service.planner_service.PlannerService` (all logic there, no ROS).
Parameters come from YAML (``--ros-args --params-file config/planner.yaml``); see that file for the
names. Service calls run in a reentrant callback group on a multi-threaded executor and wait on a
pool of worker processes, so a long 2-DOF plan never blocks 1-DOF requests; diagnostics run in
their own group.

Console script: ``ff-planner-node`` (= ``ff_planner.ros.planner_node:main``).
"""
from __future__ import annotations

import sys
from typing import Any, Optional

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from ff_msgs.srv import PlanTrajectory
from ff_msgs_py.convert import error_response, result_to_response
from ff_msgs_py.threads import in_thread
from ff_planner.library.warm import PlanFn
from ff_planner.optimize.planner import plan
from ff_planner.service.planner_service import PlannerService, RequestFields, ServiceConfigError, config_from_mapping

NODE_ONLY = ("diagnostics_period", "executor_threads")
ROS_BUILTIN = ("use_sim_time", "start_type_description_service")  # declared by every rclpy node


class PlannerNode(Node):
    """The ``ff_planner`` node. Raises ServiceConfigError on a bad configuration.

    ``plan_fn``: the planner the workers run (default: the facade ``ff_planner.optimize.planner.plan``).
    """

    def __init__(self, plan_fn: PlanFn = plan, **kwargs: Any) -> None:
        super().__init__("ff_planner", automatically_declare_parameters_from_overrides=True, **kwargs)
        values = {name: p.value for name, p in self._parameters.items()
                  if name not in ROS_BUILTIN and not name.startswith("qos_overrides")}
        self.diagnostics_period = float(values.pop("diagnostics_period", 1.0))
        self.executor_threads = int(values.pop("executor_threads", 0))
        config = config_from_mapping(values)
        if self.executor_threads <= 0:
            self.executor_threads = config.max_pending + 4
        self.service = PlannerService(config, plan_fn=plan_fn, log=lambda m: self.get_logger().warning(m))
        self.get_logger().info(
            f"starting {config.workers} planner workers (library: {config.library_path or 'off'}, "
            f"planner: {self.service.planner_name})")
        self.service.start()
        # a deep request queue: a burst of requests waits in DDS instead of being dropped (the
        # default depth of 10 loses requests); admission control then answers or refuses each one
        qos = QoSProfile(depth=max(256, 8 * config.max_pending), reliability=ReliabilityPolicy.RELIABLE)
        self._wake = self.create_guard_condition(lambda: None)   # resumes awaited work (ff_msgs_py.threads)
        self._srv = self.create_service(PlanTrajectory, "~/plan", self._on_plan, qos_profile=qos,
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
            fields = RequestFields(
                model=req.model, q0=list(req.q0), qf=list(req.qf), move_time=req.move_time,
                uncertain=list(req.uncertain), objective=req.objective, steps=req.steps,
                starts=req.starts, seed=req.seed, time_budget=req.time_budget,
                override_names=list(req.override_names), override_values=list(req.override_values))
            result = self.service.handle_fields(fields)
            try:
                result_to_response(result, res)
            except Exception as exc:  # noqa: BLE001 - e.g. a profile that cannot become a message
                error_response(res, "INTERNAL_ERROR", f"could not encode the plan: {exc}")
            src = result.extra.get("source", "?") if result.extra else "?"
            self.get_logger().info(
                f"plan {req.model or '-'} {list(req.q0)} -> {list(req.qf)} tf={req.move_time:g}: "
                f"{result.error_code} ({src}, {1e3 * result.extra.get('latency', 0.0):.1f} ms)"
                + ("" if result.success else f": {result.message}"))
        except Exception as exc:  # noqa: BLE001 - never die on a request
            self.get_logger().error(f"request failed: {exc!r}")
            error_response(res, "INTERNAL_ERROR", f"planner node error: {exc}")
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
        node.get_logger().info("ff_planner ready: service ~/plan")
        executor.spin()
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

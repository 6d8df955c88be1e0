"""A minimal node serving ff_msgs/srv/PlanTrajectory, for the ROS smoke test (tests/ff_msgs_py).

It answers with a one-step profile that holds the request's goal as q_final, so the caller can
check the interface round trip over DDS in another process.
"""
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from ff_msgs.srv import PlanTrajectory


def main() -> None:
    rclpy.init()
    node = Node("plan_echo")

    def handle(req: PlanTrajectory.Request, res: PlanTrajectory.Response) -> PlanTrajectory.Response:
        res.success = req.model == "arm1dof"
        res.error_code = res.OK if res.success else res.UNKNOWN_MODEL
        res.message = f"echo {req.model} {list(req.qf)}"
        res.q_final = list(req.qf)
        res.profile.model = req.model
        res.profile.n_steps = 1
        res.profile.step_times = [0.0, req.move_time - 0.05]
        res.profile.currents = [1.5]
        return res

    node.create_service(PlanTrajectory, "~/plan", handle)
    node.get_logger().info("plan_echo ready")
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


if __name__ == "__main__":
    main()

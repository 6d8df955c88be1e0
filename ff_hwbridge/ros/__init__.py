"""The ROS 2 nodes: ``ff_hwbridge`` (``ros.bridge_node.BridgeNode``, lifecycle: stamped current
setpoints → EPOS drives) and ``ff_sim_driver`` (``ros.sim_driver_node``: the simulated drives +
arm on the loopback CAN hub). Both modules are run as ``python -m ff_hwbridge.ros.<name>``, so
the package does not import them (nor rclpy)."""

__all__: list[str] = []

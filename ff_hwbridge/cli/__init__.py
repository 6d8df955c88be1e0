"""Command lines of the bridge: ``ff-epos`` (``cli.epos``: configure, enable and watch drives),
``ff-can-hub`` (``cli.can_hub``: the loopback CAN hub) and ``ff-sim-rig`` (``cli.sim_rig``: the
simulated drives + arm without ROS). Each module's ``main(argv)`` is the entry point; they are
run as ``python -m ff_hwbridge.cli.<name>`` too, so the package does not import them."""

__all__: list[str] = []

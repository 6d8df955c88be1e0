"""The bridge's topic-based command interface (what ros2_control's joint_state_topic_hardware_interface
publishes for an effort command interface: sensor_msgs/JointState, name + effort in N·m at the
joint): conversion to motor current, and against the simulated drive + arm (ff-sim-rig in its own
process, the bridge node in this one) the arm moves the way the effort points, a command beyond
the limit reaches the drive clamped, commands that stop end in the safe state, and a running
CurrentProfile keeps the commands out."""
from __future__ import annotations

import math
import threading
import time

import pytest

from ff_hwbridge.protocol.units import DriveUnits
from tests.support.canopen_helpers import waiter
from tests.support.ros_harness import ros_context, spinning

LIMIT = 2.0              # A, the bridge's current limit in the rig tests
SETPOINT_TIMEOUT = 1.0   # s (a loaded machine can hold the commanding thread off for 100s of ms)


def _units(**kw) -> DriveUnits:
    return DriveUnits(**{"nominal_current": 3.0, "torque_constant": 0.0267, "gear_ratio": 54.0, **kw})


def test_effort_in_nm_becomes_motor_current_by_joint_name():
    from ff_hwbridge.ros.bridge_node import command_currents

    units = [_units(), _units(torque_constant=0.0281, gear_ratio=198.0)]
    # names in another order than the bridge's, plus a joint that is not the bridge's
    amps = command_currents(["b", "gripper", "a"], [2.0, 9.0, -1.0], ("a", "b"), units)
    assert amps == pytest.approx([-1.0 / (54.0 * 0.0267), 2.0 / (198.0 * 0.0281)], rel=1e-12)
    # no names: one effort per bridge joint, in its order; NaN (ros2_control's unset command) = 0 A
    assert command_currents([], [math.nan, 1.0], ("a", "b"), units) == pytest.approx(
        [0.0, 1.0 / (198.0 * 0.0281)])


@pytest.mark.parametrize("kw, words", [
    ({"names": ["a"], "effort": [1.0]}, "no effort for joint(s) ['b']"),
    ({"names": ["a", "b"], "effort": [1.0]}, "2 name(s) but 1 effort"),
    ({"names": [], "effort": [1.0]}, "1 effort value(s) without names for 2 joint(s)"),
    ({"names": ["a", "b"], "effort": [], "position": [0.0, 0.0]}, "effort only"),
])
def test_commands_the_bridge_cannot_apply_are_refused_with_the_reason(kw, words):
    from ff_hwbridge.ros.bridge_node import CommandRejected, command_currents

    names, effort = kw.pop("names"), kw.pop("effort")
    with pytest.raises(CommandRejected) as err:
        command_currents(names, effort, ("a", "b"), [_units(), _units()], **kw)
    assert words in str(err.value)


@pytest.fixture
def bridge(rig, ros_env):
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from ff_hwbridge.ros.bridge_node import BridgeNode
    from ff_hwbridge.sim.rig import RigConfig

    rig.cmd("resetnode 1")            # a drive a previous test left in a fault (power cycle)
    rig.cmd("reset 0")
    d = RigConfig().drive_configs()[0]
    params = [Parameter("bus_interface", value="remote"), Parameter("bus_channel", value=rig.url),
              Parameter("current_limits", value=[LIMIT]),
              Parameter("nominal_currents", value=[float(d.nominal_current)]),
              Parameter("torque_constants", value=[float(d.torque_constant)]),
              Parameter("counts_per_rev", value=[float(d.counts_per_rev)]),
              Parameter("gear_ratios", value=[float(d.gear_ratio)]),
              Parameter("setpoint_timing", value="on_receipt"), Parameter("sync_period", value=0.005),
              # generous bus timeouts: the node shares this process with the test on a loaded machine;
              # the watchdog under test is setpoint_timeout
              Parameter("heartbeat_timeout", value=1.0), Parameter("sync_timeout", value=2.0),
              Parameter("master_heartbeat_timeout_ms", value=3000), Parameter("rpdo_timeout_ms", value=0),
              Parameter("setpoint_timeout", value=SETPOINT_TIMEOUT),
              Parameter("scheduler_rt_priority", value=0), Parameter("joint_state_rate", value=50.0),
              # the test's client commands as the default owner (no claim, sole publisher)
              Parameter("default_owner", value="ff_topic_interface_test")]
    with ros_context() as ctx:
        node = BridgeNode(context=ctx, parameter_overrides=params)
        client = Node("ff_topic_interface_test", context=ctx)
        with spinning(ctx, node, client):
            try:
                node.trigger_configure()
                assert node.master is not None, "configure failed"
                node.trigger_activate()
                assert node.active, node.master.fault_reason
                yield node, client, d.gear_ratio * d.torque_constant
            finally:
                node.teardown()


class _Commander:
    """Publishes JointState effort commands at ``rate`` Hz from a thread, as the hardware
    interface does at every controller-manager cycle."""

    def __init__(self, client, rate: float = 100.0) -> None:
        from sensor_msgs.msg import JointState

        self._pub = client.create_publisher(JointState, "/ff_hwbridge/joint_commands", 1)
        self._msg_type = JointState
        self._client = client
        self.effort: float | None = None
        self._stop = threading.Event()
        self._period = 1.0 / rate
        self._th = threading.Thread(target=self._run, daemon=True)
        self._th.start()

    def _run(self) -> None:
        while not self._stop.wait(self._period):
            if self.effort is None:
                continue
            msg = self._msg_type()
            msg.header.stamp = self._client.get_clock().now().to_msg()
            msg.name, msg.effort = ["joint1"], [float(self.effort)]
            self._pub.publish(msg)

    def subscribed(self) -> bool:
        return self._pub.get_subscription_count() > 0

    def close(self) -> None:
        self._stop.set()
        self._th.join(2.0)


_wait = waiter(5.0, 0.01)


@pytest.mark.integration
def test_effort_commands_move_the_simulated_arm_clamped_and_stopping_them_stops_the_drive(bridge, rig):
    from ff_msgs.msg import CurrentSetpoint

    node, client, nm_per_amp = bridge
    applied: list = []
    client.create_subscription(CurrentSetpoint, "/ff_hwbridge/applied", applied.append, 100)
    cmd = _Commander(client)
    try:
        assert _wait(cmd.subscribed)
        # +1 A worth of joint torque: the drive gets +1 A and the arm turns the positive way
        cmd.effort = 1.0 * nm_per_amp
        assert _wait(lambda: abs(rig.state()[2] - 1.0) < 0.01), rig.state()
        assert _wait(lambda: rig.state()[0] > 0.05 and rig.state()[1] > 0.0), rig.state()
        # -1 A: it slows down and turns back
        cmd.effort = -1.0 * nm_per_amp
        assert _wait(lambda: abs(rig.state()[2] + 1.0) < 0.01), rig.state()
        assert _wait(lambda: rig.state()[1] < -0.05), rig.state()
        # three times the limit: the drive gets the limit (one EPOS4 step of 3 mA below at most)
        cmd.effort = 3.0 * LIMIT * nm_per_amp
        assert _wait(lambda: rig.state()[2] > LIMIT - 0.01), rig.state()
        seen = [rig.state()[2] for _ in range(10)]
        assert all(LIMIT - 0.01 < i <= LIMIT + 1e-9 for i in seen), seen
        assert _wait(lambda: any(a.currents[0] > LIMIT - 0.01 for a in applied))
        assert max(a.currents[0] for a in applied) <= LIMIT + 1e-9
        assert node.commands_accepted > 10 and node.commands_refused == 0, node.last_command_refusal
        # the commands stop: the setpoint watchdog latches the safe state (zero current and a quick
        # stop: the drive brakes the turning arm on its quick stop ramp, up to the current limit,
        # then leaves the motor at 0 A)
        cmd.effort = None
        stopped = time.monotonic()
        assert _wait(lambda: node.master.latched), rig.state()
        assert "setpoint watchdog" in node.master.fault_reason
        assert time.monotonic() - stopped > SETPOINT_TIMEOUT * 0.9
        assert _wait(lambda: rig.state()[1] == 0.0 and rig.state()[2] == 0.0), rig.state()
        assert max(abs(a.currents[0]) for a in applied) <= LIMIT + 1e-9
        # latched: commands are refused with the reason until a fault reset
        cmd.effort = 1.0 * nm_per_amp
        assert _wait(lambda: node.commands_refused > 3)
        assert "~/fault_reset" in node.last_command_refusal
        assert rig.state()[2] == 0.0
    finally:
        cmd.close()


@pytest.mark.integration
def test_a_running_profile_keeps_the_commands_out_logged_once(bridge, rig, capfd):
    from ff_msgs.msg import CurrentSetpoint
    from ff_msgs_py.convert import setpoint_msg

    node, client, nm_per_amp = bridge
    log: list[str] = []            # the node's console log (stderr)

    def logged(words: str) -> list[str]:
        log.extend(capfd.readouterr().err.splitlines())
        return [line for line in log if words in line]

    pub = client.create_publisher(CurrentSetpoint, "/ff_hwbridge/setpoints", 10)
    cmd = _Commander(client)
    try:
        assert _wait(lambda: cmd.subscribed() and pub.get_subscription_count() > 0)
        t0 = time.time_ns() + 100_000_000
        pub.publish(setpoint_msg(t0, [0.5], 0, "p1"))
        pub.publish(setpoint_msg(t0 + 1_000_000_000, [0.0], 1, "p1", last=True))
        assert _wait(lambda: abs(rig.state()[2] - 0.5) < 0.01), rig.state()
        cmd.effort = 1.5 * nm_per_amp
        assert _wait(lambda: node.commands_refused >= 20)
        assert "profile p1 is running" in node.last_command_refusal
        assert abs(rig.state()[2] - 0.5) < 0.01 and node.commands_accepted == 0
        # the profile's last setpoint applied: the commands take over
        assert _wait(lambda: node.commands_accepted > 0)
        assert _wait(lambda: abs(rig.state()[2] - 1.5) < 0.01), rig.state()
        refusals = logged("effort command ignored")
        assert len(refusals) == 1 and "profile p1 is running" in refusals[0], refusals
        # live non-zero commands: a profile's setpoints are refused in turn
        pub.publish(setpoint_msg(time.time_ns() + 100_000_000, [-0.5], 0, "p2"))
        assert _wait(lambda: logged("profile p2 ignored: effort commands")), log
        time.sleep(0.3)
        assert abs(rig.state()[2] - 1.5) < 0.01, rig.state()
        cmd.effort = 0.0            # zero effort ends the motion: no watchdog when it stops
        assert _wait(lambda: rig.state()[2] == 0.0)
        cmd.effort = None
        time.sleep(SETPOINT_TIMEOUT * 2)
        assert not node.master.latched, node.master.fault_reason
    finally:
        cmd.close()


@pytest.mark.integration
def test_status_shows_when_the_claim_was_granted_and_the_cycles_the_drive_clipped(bridge, rig):
    """~/status: ``current_limited_cycles`` counts, per joint, the feedback cycles with statusword
    bit 11 in the latest motion (the drive's own limit lowered below the command: it clips), and
    ``claimed_since`` is the claim's grant time (zero unclaimed); ``ff-ctl status`` shows both."""
    from ff_executor.ros.ctl import format_drive_status
    from ff_msgs.msg import DriveGroupStatus
    from ff_msgs_py.claims import DriveClaim

    node, client, nm_per_amp = bridge
    status: list = []
    client.create_subscription(DriveGroupStatus, "/ff_hwbridge/status", status.append, 10)
    assert _wait(lambda: bool(status))
    assert not status[-1].claimed and (status[-1].claimed_since.sec, status[-1].claimed_since.nanosec) == (0, 0)
    assert list(status[-1].current_limited_cycles) == [0]

    # the drive's own output current limit 0.5 A (0x3001:02, mA), the command 1 A: it clips
    sdo = node.master.network[1].sdo
    with node.master._sdo_lock:
        sdo[0x3001][2].raw = 500
    cmd = _Commander(client)
    try:
        assert _wait(cmd.subscribed)
        cmd.effort = 1.0 * nm_per_amp
        assert _wait(lambda: status[-1].current_limited_cycles[0] >= 3), node.last_command_refusal
        shown = format_drive_status("/ff_hwbridge", status[-1])
        assert "joint1: Operation enabled; current limited in" in shown, shown
        cmd.effort = 0.0
        assert _wait(lambda: rig.state()[2] == 0.0), rig.state()
    finally:
        cmd.close()
        with node.master._sdo_lock:
            sdo[0x3001][2].raw = int(LIMIT * 1000)

    def since(m) -> float:
        return m.claimed_since.sec + m.claimed_since.nanosec * 1e-9

    before = time.time()
    claim = DriveClaim(client, "/ff_hwbridge")
    after = time.time()
    try:
        assert _wait(lambda: status[-1].claimed and since(status[-1]) > 0)
        granted = since(status[-1])
        assert before - 0.01 <= granted <= after + 0.01, (before, granted, after)
        assert "held since" in format_drive_status("/ff_hwbridge", status[-1])
    finally:
        claim.release()
    assert _wait(lambda: not status[-1].claimed and since(status[-1]) == 0.0)

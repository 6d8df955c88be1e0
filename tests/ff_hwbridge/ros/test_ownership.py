"""A drive only its owner commands: the bridge node in this process, the simulated drive + arm
(ff-sim-rig) in another. Client A claims and moves the arm; client B's effort commands, setpoints,
fault resets and enables are refused (the arm does not move; refusals counted in /diagnostics and
logged); A releases, B claims and moves it; an owner in a process of its own is killed and its
claim expires within the lease; the e-stop from a third node C works throughout."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from tests.support.canopen_helpers import waiter
from tests.support.ros_harness import ros_context, spinning

pytestmark = pytest.mark.integration

LIMIT = 2.0          # A
LEASE = 1.5          # s, the killed owner's lease
_wait = waiter(5.0, 0.01)


class Commander:
    """Effort commands (JointState, N·m) at 100 Hz from a thread, carrying ``token`` in
    header.frame_id."""

    def __init__(self, node, token: str = "") -> None:
        from sensor_msgs.msg import JointState

        self.pub = node.create_publisher(JointState, "/ff_hwbridge/joint_commands", 1)
        self.node, self.token, self.effort = node, token, None
        self._type = JointState
        self._stop = threading.Event()
        self._th = threading.Thread(target=self._run, daemon=True)
        self._th.start()

    def _run(self) -> None:
        while not self._stop.wait(0.01):
            if self.effort is not None:
                msg = self._type(name=["joint1"], effort=[float(self.effort)])
                msg.header.stamp = self.node.get_clock().now().to_msg()
                msg.header.frame_id = self.token
                self.pub.publish(msg)

    def close(self) -> None:
        self._stop.set()
        self._th.join(2.0)
        self.node.destroy_publisher(self.pub)


def _call(node, srv_type, name, request):
    cli = node.create_client(srv_type, name)
    assert cli.wait_for_service(timeout_sec=5.0), name
    fut = cli.call_async(request)
    assert _wait(fut.done, 10.0), name
    node.destroy_client(cli)
    return fut.result()


def test_only_the_owner_moves_the_arm_and_a_dead_owner_loses_the_drive(rig, ros_env, capfd):
    from diagnostic_msgs.msg import DiagnosticArray
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from std_msgs.msg import Bool
    from std_srvs.srv import Trigger

    from ff_hwbridge.ros.bridge_node import BridgeNode
    from ff_hwbridge.sim.rig import RigConfig
    from ff_msgs.msg import CurrentSetpoint, DriveGroupStatus
    from ff_msgs.srv import OwnerCommand
    from ff_msgs_py.claims import ClaimError, DriveClaim
    from ff_msgs_py.convert import setpoint_msg

    rig.cmd("resetnode 1")
    rig.cmd("reset 0")
    d = RigConfig().drive_configs()[0]
    nm_per_amp = d.gear_ratio * d.torque_constant
    params = [Parameter("bus_interface", value="remote"), Parameter("bus_channel", value=rig.url),
              Parameter("current_limits", value=[LIMIT]),
              Parameter("nominal_currents", value=[float(d.nominal_current)]),
              Parameter("torque_constants", value=[float(d.torque_constant)]),
              Parameter("counts_per_rev", value=[float(d.counts_per_rev)]),
              Parameter("gear_ratios", value=[float(d.gear_ratio)]),
              Parameter("setpoint_timing", value="on_receipt"), Parameter("sync_period", value=0.005),
              Parameter("heartbeat_timeout", value=1.0), Parameter("sync_timeout", value=2.0),
              Parameter("master_heartbeat_timeout_ms", value=3000), Parameter("rpdo_timeout_ms", value=0),
              Parameter("setpoint_timeout", value=1.0), Parameter("scheduler_rt_priority", value=0),
              Parameter("default_owner", value=""), Parameter("claim_lease", value=3.0)]
    log: list[str] = []

    def logged(words: str) -> list[str]:
        log.extend(capfd.readouterr().err.splitlines())
        return [line for line in log if words in line]

    with ros_context() as ctx:
        bridge = BridgeNode(context=ctx, parameter_overrides=params)
        a, b, c = (Node(n, context=ctx) for n in ("client_a", "client_b", "client_c"))
        with spinning(ctx, bridge, a, b, c, threads=4):
            owner_proc = None
            try:
                bridge.trigger_configure()
                assert bridge.master is not None, "configure failed"
                bridge.trigger_activate()
                assert bridge.active
                diags: list = []
                status: list = []
                c.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
                c.create_subscription(DriveGroupStatus, "/ff_hwbridge/status", status.append, 10)
                estop = c.create_publisher(Bool, "/ff_hwbridge/emergency_stop", 10)

                claim_a = DriveClaim(a, "/ff_hwbridge")
                assert bridge.ownership.owner == "/client_a"
                with pytest.raises(ClaimError, match="claimed by /client_a"):
                    DriveClaim(b, "/ff_hwbridge")

                # B: effort commands without and with a made-up token, a setpoint: refused
                q0 = rig.state()[0]
                cmd_b = Commander(b)
                cmd_b.effort = 1.0 * nm_per_amp
                sp_b = b.create_publisher(CurrentSetpoint, "/ff_hwbridge/setpoints", 10)
                assert _wait(lambda: sp_b.get_subscription_count() > 0)
                sp_b.publish(setpoint_msg(time.time_ns() + 50_000_000, [1.0], 0, "b", token="0" * 32))
                assert _wait(lambda: bridge.ownership.refused["command"] >= 20
                             and bridge.ownership.refused["setpoint"] >= 1)
                cmd_b.token = "f" * 32
                n = bridge.ownership.refused["command"]
                assert _wait(lambda: bridge.ownership.refused["command"] >= n + 10)
                cmd_b.effort = None
                assert rig.state()[2] == 0.0 and abs(rig.state()[0] - q0) < 1e-9, rig.state()
                assert bridge.commands_accepted == 0

                # A, the owner: its commands move the arm
                cmd_a = Commander(a, claim_a.token)
                cmd_a.effort = 1.0 * nm_per_amp
                assert _wait(lambda: abs(rig.state()[2] - 1.0) < 0.01), rig.state()
                assert _wait(lambda: rig.state()[0] > q0 + 0.01), rig.state()
                cmd_a.effort = 0.0
                assert _wait(lambda: rig.state()[2] == 0.0), rig.state()
                cmd_a.effort = None

                # e-stop from C while A owns; B cannot reset it, A can
                estop.publish(Bool(data=True))
                assert _wait(lambda: bridge.master.latched)
                res = _call(b, Trigger, "/ff_hwbridge/fault_reset", Trigger.Request())
                assert not res.success and "claimed by /client_a" in res.message, res.message
                res = _call(b, OwnerCommand, "/ff_hwbridge/owner_command",
                            OwnerCommand.Request(command=OwnerCommand.Request.FAULT_RESET, token="f" * 32))
                assert not res.success and bridge.master.latched
                res = claim_a.owner_command(OwnerCommand.Request.FAULT_RESET)
                assert res.success, res.message
                assert not bridge.master.latched

                # enable: a lifecycle activate from B is refused while A owns; A's ENABLE works
                bridge.trigger_deactivate()
                assert not bridge.active
                res = _call(b, ChangeState, "/ff_hwbridge/change_state",
                            ChangeState.Request(transition=Transition(id=Transition.TRANSITION_ACTIVATE)))
                assert not res.success and not bridge.active
                res = _call(b, OwnerCommand, "/ff_hwbridge/owner_command",
                            OwnerCommand.Request(command=OwnerCommand.Request.ENABLE, token=""))
                assert not res.success and not bridge.active
                res = claim_a.owner_command(OwnerCommand.Request.ENABLE)
                assert res.success and bridge.active, res.message

                # every kind refused, counted in /diagnostics and in the typed status, and logged
                refused = dict(bridge.ownership.refused)
                assert all(refused[k] > 0 for k in ("setpoint", "command", "fault_reset", "enable")), refused

                def counted() -> bool:
                    for m in list(diags)[-5:]:
                        v = {kv.key: kv.value for kv in m.status[0].values}
                        if v.get("owner") == "/client_a" and int(v.get("owner.refused.enable", 0)) >= 2:
                            return True
                    return False
                assert _wait(counted)
                assert _wait(lambda: any(s.owner == "/client_a" and s.claimed and s.refused > 30
                                         for s in list(status)))
                assert logged("command from") or logged("command refused"), log[-20:]
                assert logged("refused: the drive is claimed by /client_a")

                # A releases; B claims and moves the arm
                assert claim_a.release().success
                claim_b = DriveClaim(b, "/ff_hwbridge")
                cmd_b.token = claim_b.token
                cmd_b.effort = -1.0 * nm_per_amp
                assert _wait(lambda: abs(rig.state()[2] + 1.0) < 0.01), rig.state()
                cmd_b.effort = 0.0
                assert _wait(lambda: rig.state()[2] == 0.0), rig.state()
                cmd_b.effort = None
                time.sleep(0.05)
                assert claim_b.release().success
                cmd_a.close()
                cmd_b.close()

                # an owner in its own process, killed: its claim expires within the lease
                owner_proc = subprocess.Popen([sys.executable, "-m", "tests.ff_hwbridge.ros.owner_process",
                                               str(LEASE)], env=ros_env, stdout=subprocess.PIPE, text=True)
                line = owner_proc.stdout.readline()
                assert line.startswith("claimed"), line
                assert bridge.ownership.owner == "/doomed_owner"
                estop.publish(Bool(data=True))                   # C's e-stop while it owns
                assert _wait(lambda: bridge.master.latched)
                time.sleep(1.0)                                  # renewals keep it alive
                assert bridge.ownership.owner == "/doomed_owner"
                os.kill(owner_proc.pid, signal.SIGKILL)
                killed = time.monotonic()
                owner_proc.wait(10.0)
                assert waiter(LEASE + 2.0, 0.005)(lambda: not bridge.ownership.claimed)
                gone_after = time.monotonic() - killed
                # the lease runs from the owner's last renewal (each lease / 3 when on time): gone
                # at most one lease after its death (+ the bridge's 10 ms tick, on a loaded machine)
                assert gone_after <= LEASE + 0.5, gone_after
                assert _wait(lambda: logged("claim of /doomed_owner expired"))
                print(f"claim expired {gone_after:.3f} s after the owner was killed (lease {LEASE} s)")
                # no claim held: the plain fault reset is open again, and C may claim
                res = _call(c, Trigger, "/ff_hwbridge/fault_reset", Trigger.Request())
                assert res.success and not bridge.master.latched, res.message
                claim_c = DriveClaim(c, "/ff_hwbridge")
                assert bridge.ownership.owner == "/client_c"
                estop.publish(Bool(data=True))
                assert _wait(lambda: bridge.master.latched)
                assert claim_c.release().success
            finally:
                if owner_proc is not None and owner_proc.poll() is None:
                    owner_proc.kill()
                    owner_proc.wait(5.0)
                bridge.teardown()

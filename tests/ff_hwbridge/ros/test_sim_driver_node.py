"""The ff_sim_driver node in its own process: hosts the CAN hub, answers as an EPOS over it,
publishes ground truth, takes fault injection and true friction as runtime parameters, resets."""
from __future__ import annotations

import time

import canopen
import pytest
from rcl_interfaces.srv import SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from ff_hwbridge.sim.drive import DriveConfig, build_object_dictionary
from ff_msgs_py.launch import start_module, wait_for_line
from tests.support.canopen_helpers import free_port, open_network

pytestmark = pytest.mark.integration


def call(node, client, request, timeout=10.0):
    ex = SingleThreadedExecutor(context=node.context)
    ex.add_node(node)
    try:
        fut = client.call_async(request)
        ex.spin_until_future_complete(fut, timeout_sec=timeout)
    finally:
        ex.remove_node(node)
    assert fut.done(), "no answer from the service"
    return fut.result()


def set_params(node, client, **values):
    req = SetParameters.Request(parameters=[Parameter(k.replace("__", "."), value=v).to_parameter_msg()
                                            for k, v in values.items()])
    return call(node, client, req).results


def test_sim_driver_node(ros_env, rclpy_node):
    port = free_port()
    proc = start_module("ff_sim_driver", "ff_hwbridge.ros.sim_driver_node",
                        ["--ros-args", "--params-file", "config/sim_arm1dof.yaml",
                         "-p", f"hub_port:={port}", "-p", "q0:=[0.3]",
                         "-p", "true_params.pc:=0.25"], ros_env)
    net = None
    try:
        assert wait_for_line(proc, "ff_sim_driver ready", 40), proc.output()
        assert f"ws://127.0.0.1:{port}/" in proc.output() and "'pc': 0.25" in proc.output()

        # ground truth
        got: list[JointState] = []
        rclpy_node.create_subscription(JointState, "/ff_sim_driver/ground_truth", got.append, 10)
        ex = SingleThreadedExecutor(context=rclpy_node.context)
        ex.add_node(rclpy_node)
        end = time.monotonic() + 15
        while not got and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.1)
        ex.remove_node(rclpy_node)
        assert got, "no ground truth"
        assert list(got[-1].name) == ["joint1"] and list(got[-1].position) == [0.3]

        # the drive answers over the hosted hub
        net = open_network(f"ws://127.0.0.1:{port}/", interface="remote")
        emcy = []
        net.subscribe(0x81, lambda i, d, t: emcy.append(bytes(d)))
        remote = net.add_node(1, build_object_dictionary(DriveConfig()))
        remote.sdo.RESPONSE_TIMEOUT = 2.0
        assert remote.sdo[0x1018][1].raw == 0xFB
        assert remote.sdo[0x6041].raw & 0x4F == 0x40          # switch on disabled

        client = rclpy_node.create_client(SetParameters, "/ff_sim_driver/set_parameters")
        assert client.wait_for_service(timeout_sec=15)
        res = set_params(rclpy_node, client, fault__n1__emcy_code=0x4210)
        assert res[0].successful
        end = time.monotonic() + 3
        while not emcy and time.monotonic() < end:
            time.sleep(0.01)
        assert emcy and emcy[0][:2] == b"\x10\x42"
        assert remote.sdo[0x6041].raw & 0x4F == 0x08          # fault

        res = set_params(rclpy_node, client, fault__n1__sdo_silent=True)
        assert res[0].successful
        remote.sdo.RESPONSE_TIMEOUT = 0.3
        try:
            _ = remote.sdo[0x1018][1].raw
            raise AssertionError("SDO answered while silent")
        except canopen.SdoCommunicationError:
            pass
        assert set_params(rclpy_node, client, fault__n1__sdo_silent=False)[0].successful
        bad = set_params(rclpy_node, client, fault__n1__drop_fraction=2.0)[0]
        assert bad.successful is False and "range" in bad.reason      # the descriptor's 0..1
        bad = set_params(rclpy_node, client, model="scara2")[0]
        assert not bad.successful and "restart" in bad.reason
        assert set_params(rclpy_node, client, true_params__pc=0.3)[0].successful
        # friction that is not Eq. 9, at runtime: valid levels taken, bad ones refused with the reason
        assert set_params(rclpy_node, client, friction__stribeck=0.3, friction__stribeck_speed=0.05)[0].successful
        bad = set_params(rclpy_node, client, friction__coulomb_ripple=1.5)[0]
        assert not bad.successful and "coulomb_ripple" in bad.reason
        assert set_params(rclpy_node, client, friction__stribeck=0.0)[0].successful
        assert not set_params(rclpy_node, client, true_params__J=-1.0)[0].successful

        reset = rclpy_node.create_client(Trigger, "/ff_sim_driver/reset")
        assert reset.wait_for_service(timeout_sec=15)
        r = call(rclpy_node, reset, Trigger.Request())
        assert r.success and "0.3" in r.message
    finally:
        if net is not None:
            net.disconnect()
        code = proc.stop()
    assert code == 0, proc.output()


def test_a_lost_hub_faults_the_drives_and_after_the_reconnect_timeout_ends_the_node(ros_env):
    port = free_port()
    hub = start_module("ff_can_hub", "ff_hwbridge.cli.can_hub", ["--port", str(port)], ros_env)
    proc = None
    try:
        assert wait_for_line(hub, "CAN hub on ws://127.0.0.1", 30), hub.output()
        proc = start_module("ff_sim_driver", "ff_hwbridge.ros.sim_driver_node",
                            ["--ros-args", "--params-file", "config/sim_arm1dof.yaml",
                             "-p", "host_hub:=false", "-p", f"bus.channel:=ws://127.0.0.1:{port}/",
                             "-p", "reconnect_timeout:=1.5"], ros_env)
        assert wait_for_line(proc, "ff_sim_driver ready", 40), proc.output()
        t0 = time.monotonic()
        hub.stop()
        assert wait_for_line(proc, "CAN bus lost", 10), proc.output()
        end = time.monotonic() + 20
        while proc.popen.poll() is None and time.monotonic() < end:
            time.sleep(0.05)
        assert proc.popen.poll() == 3, proc.output()
        assert time.monotonic() - t0 >= 1.5
        assert "not back within 1.5 s" in proc.output()
    finally:
        if proc is not None and proc.popen.poll() is None:
            proc.stop()
        if hub.popen.poll() is None:
            hub.stop()

"""Message definitions for bags: every recorded type decodes with the independent mcap_ros2 reader."""
from __future__ import annotations

import pytest
from mcap.reader import make_reader
from mcap_ros2._dynamic import generate_dynamic
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import StoragePlugin, Writer

from ff_executor.ros.record import MESSAGE_TYPES
from ff_msgs.action import ExecuteProfile
from ff_msgs.msg import CurrentSetpoint
from ff_msgs_py.definitions import SEPARATOR, ff_definitions, message_definition


def decoder(name: str, text: str):
    """mcap_ros2's decoder for a definition. Its name check (rosidl's ``^[A-Z][A-Za-z0-9]*$`` after
    the _Request/_Response/_Goal/_Result/_Feedback suffixes) refuses rosidl's own action wrapper
    name ``X_FeedbackMessage``; the definition text is what is checked here, under an accepted name."""
    alias = name.replace("_FeedbackMessage", "FeedbackMessage")
    return generate_dynamic(alias, text)[alias]


def test_ff_definitions_split_srv_and_action_like_rosidl():
    d = ff_definitions()
    for name in ("ff_msgs/msg/CurrentProfile", "ff_msgs/msg/CurrentSetpoint", "ff_msgs/srv/PlanTrajectory_Request",
                 "ff_msgs/srv/PlanTrajectory_Response", "ff_msgs/action/ExecuteProfile_Goal",
                 "ff_msgs/action/ExecuteProfile_Result", "ff_msgs/action/ExecuteProfile_Feedback",
                 "ff_msgs/action/ExecuteProfile_FeedbackMessage"):
        assert name in d
    assert "float64 elapsed" in d["ff_msgs/action/ExecuteProfile_Feedback"]
    assert "---" not in d["ff_msgs/action/ExecuteProfile_Result"]


def test_definitions_carry_every_dependency_once():
    text = message_definition("ff_msgs/action/ExecuteProfile_Goal")
    heads = [line for line in text.splitlines() if line.startswith("MSG: ")]
    assert sorted(heads) == ["MSG: builtin_interfaces/msg/Time", "MSG: ff_msgs/msg/CurrentProfile"]
    assert text.count(SEPARATOR) == 2
    with pytest.raises(KeyError):
        message_definition("ff_msgs/msg/Nope")
    with pytest.raises(KeyError):
        message_definition("nope_msgs/msg/Nope")


@pytest.mark.parametrize("name", sorted(MESSAGE_TYPES))
def test_every_recorded_type_decodes_with_mcap_ros2(name):
    msg = MESSAGE_TYPES[name]()
    out = decoder(name, message_definition(name))(serialize_message(msg))
    assert type(out).__name__ == name.rsplit("/", 1)[1].replace("_FeedbackMessage", "FeedbackMessage")


def test_feedback_and_setpoint_values_survive_a_bag_round_trip(tmp_path):
    fb = ExecuteProfile.Impl.FeedbackMessage()
    fb.goal_id.uuid = list(range(16))
    fb.feedback.elapsed = 0.25
    fb.feedback.commanded_currents = [2.27]
    fb.feedback.measured_positions = [0.125]
    sp = CurrentSetpoint(currents=[1.5, -2.0], seq=3, profile_id="abc", last=True)
    sp.stamp.sec, sp.stamp.nanosec = 12, 345
    bag = tmp_path / "bag"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        for topic, name, m in (("/ff_executor/execute/_action/feedback",
                                "ff_msgs/action/ExecuteProfile_FeedbackMessage", fb),
                               ("/ff_hwbridge/setpoints", "ff_msgs/msg/CurrentSetpoint", sp)):
            c = w.add_connection(topic, name, msgdef=message_definition(name), rihs01="RIHS01_" + "0" * 64)
            w.write(c, 1000, serialize_message(m))
    (mcap,) = bag.glob("*.mcap")
    with open(mcap, "rb") as f:
        got = {ch.topic: decoder(schema.name, schema.data.decode())(m.data)
               for schema, ch, m in make_reader(f).iter_messages()}
    f_out = got["/ff_executor/execute/_action/feedback"]
    assert list(f_out.goal_id.uuid) == list(range(16))
    assert f_out.feedback.elapsed == 0.25 and list(f_out.feedback.measured_positions) == [0.125]
    s_out = got["/ff_hwbridge/setpoints"]
    assert list(s_out.currents) == [1.5, -2.0] and s_out.seq == 3 and s_out.profile_id == "abc" and s_out.last
    assert (s_out.stamp.sec, s_out.stamp.nanosec) == (12, 345)

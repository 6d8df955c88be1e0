"""Message definitions for bags: every recorded type decodes with the independent mcap_ros2 reader."""
from __future__ import annotations

import re

import pytest
from mcap.reader import make_reader
from mcap_ros2._dynamic import generate_dynamic
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import StoragePlugin, Writer

from ff_executor.ros.record import MESSAGE_TYPES
from ff_msgs.action import ExecuteProfile
from ff_msgs.msg import CurrentProfile, CurrentSetpoint
from ff_msgs_py.definitions import SEPARATOR, ff_definitions, message_definition


def decoder(name: str, text: str):
    """mcap_ros2's decoder for a definition. Its name check (rosidl's ``^[A-Z][A-Za-z0-9]*$`` after
    the _Request/_Response/_Goal/_Result/_Feedback suffixes) refuses rosidl's own action wrapper
    name ``X_FeedbackMessage``, and its field parser names nested types ``pkg/Type`` only, where
    the wrapper nests ``pkg/action/X_Feedback`` (rosidl's name, which the type hash covers); the
    definition's structure is what is checked here, under names it accepts."""
    alias = name.replace("_FeedbackMessage", "FeedbackMessage")
    text = re.sub(r"\b(\w+)/action/(\w+)_Feedback\b", r"\1/\2Feedback", text)
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
    assert sorted(heads) == ["MSG: builtin_interfaces/Time", "MSG: ff_msgs/CurrentProfile"]
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


# sensor_msgs/msg/JointState as rosbag2 (Jazzy, LocalMessageDefinitionSource) embeds it in an MCAP
# schema: the type's own .msg text, then each dependency once, after a line of 80 '=' and a
# header 'MSG: pkg/Type' naming it as the field does (no 'msg' folder). Written by hand from that
# documented layout, comments and all, not produced by our own writer.
ROSBAG2_JOINT_STATE = """# This is a message that holds data to describe the state of a set of torque controlled joints.
std_msgs/Header header

string[] name
float64[] position
float64[] velocity
float64[] effort

================================================================================
MSG: std_msgs/Header
# Standard metadata for higher-level stamped data types.
builtin_interfaces/Time stamp

# Transform frame with which this data is associated.
string frame_id

================================================================================
MSG: builtin_interfaces/Time
# This message communicates ROS Time defined here:
int32 sec

# The nanoseconds component, valid in the range [0, 1e9), to be added to the seconds component.
uint32 nanosec
"""


def _sections(text: str) -> dict[str, list[str]]:
    """{header (own type: ''): field lines without comments or blanks} of a ros2msg text."""
    out: dict[str, list[str]] = {}
    for i, sec in enumerate(text.split(SEPARATOR + "\n")):
        lines = sec.splitlines()
        head = ""
        if i:
            assert lines[0].startswith("MSG: "), lines[0]
            head, lines = lines[0], lines[1:]
        out[head] = [ln.split("#", 1)[0].strip() for ln in lines if ln.split("#", 1)[0].strip()]
    return out


def test_definition_matches_the_layout_rosbag2_writes():
    ours = _sections(message_definition("sensor_msgs/msg/JointState"))
    assert ours == _sections(ROSBAG2_JOINT_STATE)
    for name in MESSAGE_TYPES:
        for head in _sections(message_definition(name)):
            if head:
                pkg_type = head.removeprefix("MSG: ")
                assert pkg_type.count("/") == 1 or "/action/" in pkg_type, \
                    f"{name}: header {head!r} is not 'MSG: pkg/Type'"


def _rihs01(name: str) -> str:
    """The type hash rosidl generated for a type (share/<pkg>/*/*.json), as a publisher offers it."""
    import json
    import sys
    from pathlib import Path

    pkg = name.split("/")[0]
    for f in sorted((Path(sys.prefix) / "share" / pkg).glob("*/*.json")):
        for entry in json.loads(f.read_text())["type_hashes"]:
            if entry["type_name"] == name:
                return entry["hash_string"]
    raise KeyError(name)


def test_every_recorded_type_reads_back_with_rosbags_anyreader(tmp_path):
    """AnyReader resolves every nested type from the headers and checks the publisher's type hash
    (rosidl's, as a recording stores it) against the definition's structure."""
    from rosbags.highlevel import AnyReader

    # messages as the stack publishes them (float64 arrays filled: Fast CDR pads an EMPTY float64
    # sequence to 8 bytes where rosbags' size check does not, a difference real traffic never has)
    samples = {name: MESSAGE_TYPES[name]() for name in MESSAGE_TYPES}
    js = samples["sensor_msgs/msg/JointState"]
    js.name, js.position, js.velocity, js.effort = ["j1"], [0.5], [-1.25], [0.75]
    samples["ff_msgs/msg/CurrentSetpoint"] = CurrentSetpoint(currents=[1.5], seq=2, profile_id="p")
    samples["ff_msgs/msg/CurrentProfile"] = CurrentProfile(
        profile_id="p", model="arm1dof", joint_names=["j1"], q0=[0.0], qf=[1.0], step_times=[0.0, 0.5],
        currents=[2.0], n_steps=1, coast=0.05, move_time=1.0, predicted_rest=[1.0])
    fb = samples["ff_msgs/action/ExecuteProfile_FeedbackMessage"]
    fb.feedback.elapsed = 0.25
    fb.feedback.commanded_currents, fb.feedback.measured_positions = [2.0], [0.125]
    fb.feedback.measured_velocities = [3.0]
    bag = tmp_path / "bag"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        for i, name in enumerate(sorted(MESSAGE_TYPES)):
            c = w.add_connection(f"/t{i}", name, msgdef=message_definition(name),
                                 rihs01=_rihs01(name))
            w.write(c, 1000 + i, serialize_message(samples[name]))
    seen = {}
    with AnyReader([bag]) as reader:
        for conn, _t, raw in reader.messages():
            seen[conn.msgtype] = reader.deserialize(raw, conn.msgtype)
    assert sorted(seen) == sorted(MESSAGE_TYPES)
    assert list(seen["sensor_msgs/msg/JointState"].velocity) == [-1.25]
    assert list(seen["ff_msgs/action/ExecuteProfile_FeedbackMessage"].feedback.measured_positions) == [0.125]
    assert list(seen["ff_msgs/msg/CurrentProfile"].step_times) == [0.0, 0.5]

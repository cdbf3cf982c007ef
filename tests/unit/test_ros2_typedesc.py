"""ROS 2 message types from our .msg definitions: the REP-2011 type hashes ROS 2 computes for them,
and ROS 2's DDS names.

The published hashes are rosidl's own for these types: the TYPE_HASH constants of the C code
rosidl generated for the micro-ROS Arduino library (github.com/micro-ROS/micro_ros_arduino,
src/*/msg/detail/*__struct.h at commit 3037aab5, May 2023: ROS 2 rolling at Iron's release);
other projects' sources quote the same values (geometry_msgs/msg/PoseWithCovarianceStamped's,
std_msgs/msg/String's). A wrong field, type, order, array size or nested name in our
definitions, or a slip in the hashing, changes them.
"""

from __future__ import annotations

import json

import pytest

from pfdoa.ros2 import typedesc as td
from pfdoa.sinks import ros

pytestmark = pytest.mark.unit

PUBLISHED = {
    "builtin_interfaces/msg/Time": "b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197",
    "std_msgs/msg/Header": "f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01",
    "geometry_msgs/msg/Point": "6963084842a9b04494d6b2941d11444708d892da2f4b09843b9c43f42a7f6881",
    "geometry_msgs/msg/Quaternion": "8a765f66778c8ff7c8ab94afcc590a2ed5325a1d9a076ffff38fbce36f458684",
    "geometry_msgs/msg/Vector3": "cc12fe83e4c02719f1ce8070bfd14aecd40f75a96696a67a2a1f37f7dbb0765d",
    "geometry_msgs/msg/Pose": "d501954e9476cea2996984e812054b68026ae0bfae789d9a10b23daf35cc90fa",
    "geometry_msgs/msg/PoseWithCovariance": "9a7c0fd234b7f45c6098745ecccd773ca1085670e64107135397aee31c02e1bb",
    "geometry_msgs/msg/PoseWithCovarianceStamped": "26432f9803e43727d3c8f668d1fdb3c630f548af631e2f4e31382371bfea3b6e",
    "geometry_msgs/msg/Twist": "9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a",
    "geometry_msgs/msg/TwistWithCovariance": "49f574f033f095d8b6cd1beaca5ca7925e296e84af1716d16c89d38b059c8c18",
    "geometry_msgs/msg/Transform": "beb83fbe698636351461f6f35d1abb20010c43d55374d81bd041f1ba2581fddc",
    "geometry_msgs/msg/TransformStamped": "0a241f87d04668d94099cbb5ba11691d5ad32c2f29682e4eb5653424bd275206",
    "nav_msgs/msg/Odometry": "3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "tf2_msgs/msg/TFMessage": "e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "diagnostic_msgs/msg/DiagnosticArray": "5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e",
    "diagnostic_msgs/msg/DiagnosticStatus": "b0e3e692ea2d54a8af2f4ef1930e81556a2db55216b771f8a7d2724ed47bf0e4",
    "diagnostic_msgs/msg/KeyValue": "d68081eaa540288c5440753baecef0c4e16e81a5f78ad68902ded5100413bb42",
    # std_msgs/msg/String, from the same source: the simplest type, a check of the method alone.
    "std_msgs/msg/String": "df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
}


@pytest.fixture(scope="module")
def types():
    out: dict[str, td.MsgType] = {}
    for name, text in ros.LIVE_MSGDEFS.items():
        out.update(td.parse_msgdef(name, text))
    out.update(td.parse_msgdef("std_msgs/msg/String", "string data"))
    return out


def test_every_type_we_publish_or_read_has_ros2s_own_hash(types):
    assert set(PUBLISHED) == set(types)  # every type of the live output, and each of its parts
    for name, digest in PUBLISHED.items():
        assert td.type_hash(name, types) == "RIHS01_" + digest, name


def test_the_hashed_text_is_the_type_description_without_defaults(types):
    doc = json.loads(td.hashable_json("geometry_msgs/msg/Quaternion", types))
    # Quaternion's .msg gives w a default of 1: defaults are not part of a type's identity.
    assert doc == {"type_description": {"type_name": "geometry_msgs/msg/Quaternion", "fields": [
        {"name": n, "type": {"type_id": 11, "capacity": 0, "string_capacity": 0, "nested_type_name": ""}}
        for n in "xyzw"]}, "referenced_type_descriptions": []}
    status = types["diagnostic_msgs/msg/DiagnosticStatus"]
    assert [f.name for f in status.fields] == ["level", "name", "message", "hardware_id", "values"]  # no constants
    assert status.field("level").type.type_id() == 16  # .msg byte: an octet
    assert status.field("values").type.type_id() == 145  # unbounded sequence of a nested type
    assert types["geometry_msgs/msg/PoseWithCovariance"].field("covariance").type.type_id() == 59  # float64[36]
    assert td.referenced("nav_msgs/msg/Odometry", types) == sorted([
        "builtin_interfaces/msg/Time", "std_msgs/msg/Header", "geometry_msgs/msg/PoseWithCovariance",
        "geometry_msgs/msg/Pose", "geometry_msgs/msg/Point", "geometry_msgs/msg/Quaternion",
        "geometry_msgs/msg/TwistWithCovariance", "geometry_msgs/msg/Twist", "geometry_msgs/msg/Vector3"])


def test_a_changed_field_changes_the_hash(types):
    changed = td.parse_msgdef("geometry_msgs/msg/Point", "float64 x\nfloat32 y\nfloat64 z")
    assert td.type_hash("geometry_msgs/msg/Point", changed) != "RIHS01_" + PUBLISHED["geometry_msgs/msg/Point"]
    renamed = td.parse_msgdef("geometry_msgs/msg/Point", "float64 x\nfloat64 y\nfloat64 h")
    assert td.type_hash("geometry_msgs/msg/Point", renamed) != "RIHS01_" + PUBLISHED["geometry_msgs/msg/Point"]


def test_field_types_of_the_msg_format():
    t = td.parse_msgdef("pkg/msg/All", "\n".join([
        "# a comment line", "int32 A=3  # a constant", "string<=8 s", "uint8[4] fixed", "float64[] unbounded",
        "int16[<=5] bounded", "string<=3[2] names", "Other other", "pkg2/Far[] far",
        "=" * 80, "MSG: pkg/Other", "bool b", "=" * 80, "MSG: pkg2/Far", "char c"]))
    f = {x.name: x.type for x in t["pkg/msg/All"].fields}
    assert list(f) == ["s", "fixed", "unbounded", "bounded", "names", "other", "far"]
    assert (f["s"].type_id(), f["s"].string_bound) == (21, 8)
    assert (f["fixed"].type_id(), f["fixed"].array) == (51, 4)
    assert f["unbounded"].type_id() == 155 and f["bounded"].type_id() == 100 and f["bounded"].bound == 5
    assert (f["names"].type_id(), f["names"].array, f["names"].string_bound) == (69, 2, 3)
    assert (f["other"].base, f["other"].type_id()) == ("pkg/msg/Other", 1)
    assert (f["far"].base, f["far"].type_id()) == ("pkg2/msg/Far", 145)
    assert t["pkg2/msg/Far"].fields[0].type.type_id() == 3  # a ROS 2 .msg char is a uint8
    with pytest.raises(ValueError, match="not defined"):
        td.parse_msgdef("pkg/msg/A", "Missing m")
    with pytest.raises(ValueError, match="only strings"):
        td.parse_msgdef("pkg/msg/A", "int32<=4 n")


def test_ros2s_dds_names():
    assert td.dds_type_name("geometry_msgs/msg/PoseWithCovarianceStamped") == \
        "geometry_msgs::msg::dds_::PoseWithCovarianceStamped_"
    assert td.dds_type_name("std_msgs/Header") == "std_msgs::msg::dds_::Header_"
    assert td.dds_topic_name("/pfdoa/pose") == "rt/pfdoa/pose"
    assert td.dds_topic_name("/tf_static") == "rt/tf_static"
    with pytest.raises(ValueError):
        td.dds_topic_name("pfdoa/pose")  # relative: resolve it against the namespace first
    assert td.user_data("std_msgs/msg/String", td.parse_msgdef("std_msgs/msg/String", "string data")) == \
        b"typehash=RIHS01_" + PUBLISHED["std_msgs/msg/String"].encode() + b";"

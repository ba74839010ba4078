"""rmw_zenoh's keys, liveliness tokens and attachments as the bridge makes them, against the
literal examples of ros2/rmw_zenoh's docs/design.md and zenoh-ext's own serializer; and
zenoh-bridge-ros2dds's plain keys (zenoh-plugin-ros2dds, ros2_utils.rs ros2_name_to_key_expr).
"""

from __future__ import annotations

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st
from zenoh.ext import Int64, z_serialize

from voxshape.services.ros2 import msgs, rmw
from voxshape.services.ros2.rmw import Attachment, RmwError

# docs/design.md uses std_msgs/String and example_interfaces/AddTwoInts in its examples.
STRING = msgs.RosType(
    "std_msgs/msg/String",
    "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
)
ADD_TWO_INTS = msgs.RosType(
    "example_interfaces/srv/AddTwoInts",
    "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a",
)


def test_topic_keys_are_design_md_s_examples():
    """design.md, "Topic and Service name mapping to Zenoh key expressions", examples using
    the demo_nodes_cpp package."""
    assert rmw.topic_key(0, rmw.fully_qualified("/", "chatter"), STRING) == (
        "0/chatter/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    )
    assert rmw.topic_key(0, rmw.fully_qualified("/robot1", "chatter"), STRING) == (
        "0/robot1/chatter/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    )
    assert rmw.topic_key(2, "/add_two_ints", ADD_TWO_INTS) == (
        "2/add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/"
        "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"
    )


def test_liveliness_tokens_are_design_md_s_examples():
    """design.md, "Graph Cache", examples using the demo_nodes_cpp package (domain 2)."""
    listener = rmw.RosNodeName(2, "aac3178e146ba6f1fc6e6a4085e77f21", "listener")
    assert rmw.node_token(listener) == (
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    )
    assert rmw.entity_token(listener, 10, "MS", "/chatter", STRING, rmw.Qos(depth=10)) == (
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
        "std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,10:,:,:,,"
    )
    talker = rmw.RosNodeName(2, "8b20917502ee955ac4476e0266340d5c", "talker")
    assert rmw.entity_token(talker, 10, "MP", "/chatter", STRING, rmw.Qos(depth=7)) == (
        "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
        "std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,"
    )


def test_a_namespace_and_a_best_effort_qos_are_mangled_and_written():
    node = rmw.RosNodeName(0, "ab", "voxshape_r1", "/tb3")
    token = rmw.entity_token(node, 1, "MS", "/tb3/scan", msgs.LASER_SCAN, rmw.Qos(2, depth=5))
    assert token.startswith("@ros2_lv/0/ab/0/1/MS/%/%tb3/voxshape_r1/%tb3%scan/")
    assert token.endswith("/2::,5:,:,:,,")  # liveliness_utils.cpp qos_to_keyexpr
    assert rmw.Qos().keyexpr() == "::,:,:,:,,"  # every part rmw_zenoh's default


def test_ros2dds_keys_are_the_names_without_their_leading_slash():
    assert rmw.ros2dds_key(rmw.fully_qualified("/", "cmd_vel")) == "cmd_vel"
    assert rmw.ros2dds_key(rmw.fully_qualified("/bot1", "scan")) == "bot1/scan"
    assert rmw.fully_qualified("/bot1", "/scan") == "/scan"  # absolute stays


def test_bad_ros_names_are_refused():
    assert rmw.check_name("/tb3", "namespace") == "/tb3"
    for bad in ("/a b", "x*", "a//b", "@x", ""):
        with pytest.raises(RmwError, match=r"a ROS name|empty part"):
            rmw.check_name(bad, "namespace")


@given(
    seq=st.integers(-(2**63), 2**63 - 1),
    stamp=st.integers(-(2**63), 2**63 - 1),
    gid=st.binary(min_size=16, max_size=16),
)
def test_attachments_are_zenoh_ext_serializations_in_both_formats(seq, stamp, gid):
    """design.md, "Publishers": int64 LE sequence number, int64 LE timestamp, a length byte
    (16) and the GID: zenoh-ext's serialization of (int64, int64, bytes), 33 bytes; before
    0.2.4, each preceded by its name as a string, 77 bytes."""
    a = Attachment(seq, stamp, gid)
    new = rmw.encode_attachment(a, "33")
    assert new == z_serialize((Int64(seq), Int64(stamp), gid)).to_bytes()
    assert len(new) == 33 and rmw.decode_attachment(new) == (a, "33")
    old = rmw.encode_attachment(a, "77")
    names = ("sequence_number", "source_timestamp", "source_gid")
    reference = (names[0], Int64(seq), names[1], Int64(stamp), names[2], gid)
    assert old == z_serialize(reference).to_bytes()
    assert len(old) == 77 and rmw.decode_attachment(old) == (a, "77")


def test_an_attachment_of_neither_format_is_refused_naming_both():
    for raw in (b"", bytes(32), struct.pack("<qq", 1, 2) + bytes([15]) + bytes(16), bytes(77)):
        with pytest.raises(RmwError, match="neither rmw_zenoh's 33-byte format"):
            rmw.decode_attachment(raw)
    with pytest.raises(RmwError, match="a GID is 16 bytes"):
        rmw.encode_attachment(Attachment(1, 2, b"short"))


def test_a_publisher_s_gid_is_16_bytes_of_its_token():
    gid = rmw.entity_gid("@ros2_lv/0/ab/0/3/MP/%/%/voxshape_r1/%cmd_vel/x/y/::,10:,:,:,,")
    assert len(gid) == 16 and gid != rmw.entity_gid("another token")

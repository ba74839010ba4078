"""The bridge's CDR codec against an independent one: messages the `rosbags` package encodes
(little- and big-endian, NaN and inf in the scans) decode in ours to the same fields, and
ours decode in rosbags; the pinned type hashes are rosbags' own. Bad bytes are refused with
a message that says where."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from voxshape.services.ros2 import msgs
from voxshape.services.ros2.cdr import CdrError

TYPES = get_typestore(Stores.ROS2_JAZZY)
T = TYPES.types

finite = st.floats(-1e6, 1e6, allow_nan=False, width=32)
reading = st.one_of(
    st.floats(0, 100, width=32), st.just(math.inf), st.just(-math.inf), st.just(math.nan)
)
stamps = st.tuples(st.integers(-(2**31), 2**31 - 1), st.integers(0, 2**32 - 1))
frames = st.text(st.characters(codec="utf-8", exclude_characters="\x00"), max_size=20)
doubles = st.floats(allow_nan=False, allow_infinity=False, width=64)
endian = st.booleans()


def header(stamp: tuple[int, int], frame: str) -> object:
    return T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=stamp[0], nanosec=stamp[1]), frame_id=frame
    )


def same(a: np.ndarray, b: np.ndarray) -> bool:
    return np.array_equal(np.asarray(a, np.float32), np.asarray(b, np.float32), equal_nan=True)


@pytest.mark.parametrize("store", [Stores.ROS2_HUMBLE, Stores.ROS2_JAZZY, Stores.ROS2_KILTED])
def test_the_pinned_type_hashes_are_rosbags_own(store):
    typestore = get_typestore(store)
    for ros_type in msgs.ROS_TYPES:
        assert ros_type.type_hash == typestore.hash_rihs01(ros_type.name), ros_type.name


def test_rosbags_hashes_as_rmw_zenoh_does():
    """rosbags is a fair reference: its hash of std_msgs/String is the one in rmw_zenoh's
    design document's keys (docs/design.md, "Topic and Service name mapping")."""
    assert TYPES.hash_rihs01("std_msgs/msg/String") == (
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    )


@settings(max_examples=60, deadline=None)
@given(
    stamp=stamps,
    frame=frames,
    angles=st.lists(finite, min_size=7, max_size=7),
    ranges=st.lists(reading, max_size=400),
    intensities=st.lists(st.floats(0, 1e4, width=32), max_size=10),
    little=endian,
)
def test_a_scan_reads_the_same_both_ways(stamp, frame, angles, ranges, intensities, little):
    theirs = T["sensor_msgs/msg/LaserScan"](
        header(stamp, frame),
        *angles,
        np.array(ranges, np.float32),
        np.array(intensities, np.float32),
    )
    raw = bytes(TYPES.serialize_cdr(theirs, "sensor_msgs/msg/LaserScan", little_endian=little))
    ours = msgs.decode_laser_scan(raw)
    assert (ours.header.stamp.sec, ours.header.stamp.nanosec, ours.header.frame_id) == (
        *stamp,
        frame,
    )
    fields = (ours.angle_min, ours.angle_max, ours.angle_increment, ours.time_increment)
    fields += (ours.scan_time, ours.range_min, ours.range_max)
    assert np.array_equal(np.float32(fields), np.float32(angles))
    assert same(ours.ranges, ranges) and same(ours.intensities, intensities)
    again = msgs.encode_laser_scan(ours, little_endian=little)
    assert again == raw  # byte for byte, padding included
    back = TYPES.deserialize_cdr(again, "sensor_msgs/msg/LaserScan")
    assert same(back.ranges, ranges) and back.header.frame_id == frame


@settings(max_examples=60, deadline=None)
@given(
    stamp=stamps,
    frames_=st.tuples(frames, frames),
    values=st.lists(doubles, min_size=13, max_size=13),
    covariances=st.tuples(
        st.lists(doubles, min_size=36, max_size=36), st.lists(doubles, min_size=36, max_size=36)
    ),
    little=endian,
)
def test_odometry_reads_the_same_both_ways(stamp, frames_, values, covariances, little):
    p, q, lin, ang = values[:3], values[3:7], values[7:10], values[10:13]
    pose = T["geometry_msgs/msg/Pose"](
        T["geometry_msgs/msg/Point"](*p), T["geometry_msgs/msg/Quaternion"](*q)
    )
    twist = T["geometry_msgs/msg/Twist"](
        T["geometry_msgs/msg/Vector3"](*lin), T["geometry_msgs/msg/Vector3"](*ang)
    )
    theirs = T["nav_msgs/msg/Odometry"](
        header(stamp, frames_[0]),
        frames_[1],
        T["geometry_msgs/msg/PoseWithCovariance"](pose, np.array(covariances[0])),
        T["geometry_msgs/msg/TwistWithCovariance"](twist, np.array(covariances[1])),
    )
    raw = bytes(TYPES.serialize_cdr(theirs, "nav_msgs/msg/Odometry", little_endian=little))
    ours = msgs.decode_odometry(raw)
    assert ours.header.frame_id == frames_[0] and ours.child_frame_id == frames_[1]
    assert (ours.position, ours.orientation) == (tuple(p), tuple(q))
    assert (ours.linear, ours.angular) == (tuple(lin), tuple(ang))
    assert ours.pose_covariance == tuple(covariances[0])
    assert ours.twist_covariance == tuple(covariances[1])
    assert msgs.encode_odometry(ours, little_endian=little) == raw
    back = TYPES.deserialize_cdr(msgs.encode_odometry(ours, little), "nav_msgs/msg/Odometry")
    assert back.pose.pose.orientation.w == q[3] and back.twist.twist.angular.z == ang[2]


@settings(max_examples=60, deadline=None)
@given(
    lin=st.tuples(doubles, doubles, doubles),
    ang=st.tuples(doubles, doubles, doubles),
    stamp=stamps,
    frame=frames,
    little=endian,
)
def test_twists_read_the_same_both_ways(lin, ang, stamp, frame, little):
    ours = msgs.TwistMsg(lin, ang)
    back = TYPES.deserialize_cdr(msgs.encode_twist(ours, little), "geometry_msgs/msg/Twist")
    assert (back.linear.x, back.linear.y, back.linear.z) == lin
    assert (back.angular.x, back.angular.y, back.angular.z) == ang
    theirs = T["geometry_msgs/msg/Twist"](
        T["geometry_msgs/msg/Vector3"](*lin), T["geometry_msgs/msg/Vector3"](*ang)
    )
    raw = bytes(TYPES.serialize_cdr(theirs, "geometry_msgs/msg/Twist", little_endian=little))
    assert msgs.decode_twist(raw) == ours
    stamped = msgs.TwistStampedMsg(msgs.HeaderMsg(msgs.TimeMsg(*stamp), frame), ours)
    raw = msgs.encode_twist_stamped(stamped, little)
    back = TYPES.deserialize_cdr(raw, "geometry_msgs/msg/TwistStamped")
    assert (back.header.stamp.sec, back.header.stamp.nanosec) == stamp
    assert back.header.frame_id == frame and back.twist.angular.z == ang[2]
    theirs = T["geometry_msgs/msg/TwistStamped"](header(stamp, frame), theirs)
    raw = TYPES.serialize_cdr(theirs, "geometry_msgs/msg/TwistStamped", little_endian=little)
    assert msgs.decode_twist_stamped(raw) == stamped


def scan_bytes() -> bytes:
    return msgs.encode_laser_scan(
        msgs.LaserScanMsg(msgs.HeaderMsg(), 0, 1, 0.1, 0, 0.1, 0.1, 3.5, np.ones(10, np.float32))
    )


def test_cut_or_foreign_bytes_are_refused_saying_where():
    raw = scan_bytes()
    with pytest.raises(CdrError, match=r"sensor_msgs/LaserScan: ends after 30 bytes"):
        msgs.decode_laser_scan(raw[:30])
    with pytest.raises(CdrError, match="not plain CDR"):
        msgs.decode_laser_scan(b"\x00\x07" + raw[2:])  # XCDR2
    with pytest.raises(CdrError, match="after the last field"):
        msgs.decode_laser_scan(raw + bytes(8))
    with pytest.raises(CdrError, match="shorter than the CDR header"):
        msgs.decode_twist(b"\x00")
    huge = bytearray(raw)
    huge[-48:-44] = (2**31).to_bytes(4, "little")  # the count of the 10 ranges
    with pytest.raises(CdrError, match="a sequence of 2147483648 elements"):
        msgs.decode_laser_scan(bytes(huge))


def test_a_time_of_seconds_keeps_its_nanoseconds():
    t = msgs.TimeMsg.of(1795787072.25)
    assert (t.sec, t.nanosec) == (1795787072, 250_000_000) and t.seconds == 1795787072.25

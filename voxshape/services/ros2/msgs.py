"""The ROS 2 messages the bridge speaks, as plain dataclasses with their CDR codec: it reads
sensor_msgs/LaserScan and nav_msgs/Odometry and writes geometry_msgs/Twist or TwistStamped.
Nested messages are flattened where nothing needs them whole: a Point, Vector3 or Quaternion
is a tuple, a covariance a tuple of 36.

Each type carries its DDS name and its REP 2011 type hash (RIHS01), pinned: rmw_zenoh puts
both in every key, so a wrong one is a silent mismatch. They are the same in Humble, Jazzy
and Kilted; tests/test_ros2_codec.py checks them against the `rosbags` package's own.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from voxshape.services.ros2.cdr import CdrReader, CdrWriter

Triple = tuple[float, float, float]
ZERO3: Triple = (0.0, 0.0, 0.0)
COVARIANCE = 36  # a 6x6 row-major covariance


@dataclass(frozen=True)
class TimeMsg:
    """builtin_interfaces/Time."""

    sec: int = 0
    nanosec: int = 0

    @classmethod
    def of(cls, seconds: float) -> TimeMsg:
        whole = int(seconds // 1)
        return cls(whole, min(999_999_999, round((seconds - whole) * 1e9)))

    @property
    def seconds(self) -> float:
        return self.sec + self.nanosec * 1e-9


@dataclass(frozen=True)
class HeaderMsg:
    """std_msgs/Header."""

    stamp: TimeMsg = field(default_factory=TimeMsg)
    frame_id: str = ""


@dataclass(frozen=True)
class TwistMsg:
    """geometry_msgs/Twist: linear and angular velocity (m/s, rad/s), each x y z."""

    linear: Triple = ZERO3
    angular: Triple = ZERO3


@dataclass(frozen=True)
class TwistStampedMsg:
    """geometry_msgs/TwistStamped (what diff_drive_controller takes since Jazzy)."""

    header: HeaderMsg
    twist: TwistMsg


@dataclass(frozen=True, eq=False)
class LaserScanMsg:
    """sensor_msgs/LaserScan: angles in the laser's frame, ranges in metres (inf: nothing
    within range_max, -inf: too close, NaN: no valid reading, as REP 117 says)."""

    header: HeaderMsg
    angle_min: float
    angle_max: float
    angle_increment: float
    time_increment: float
    scan_time: float
    range_min: float
    range_max: float
    ranges: np.ndarray
    intensities: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))


@dataclass(frozen=True)
class OdometryMsg:
    """nav_msgs/Odometry: the pose (in header.frame_id, usually odom) and the twist (in
    child_frame_id, usually base_link)."""

    header: HeaderMsg
    child_frame_id: str
    position: Triple
    orientation: tuple[float, float, float, float]  # quaternion x y z w
    pose_covariance: tuple[float, ...] = (0.0,) * COVARIANCE
    linear: Triple = ZERO3
    angular: Triple = ZERO3
    twist_covariance: tuple[float, ...] = (0.0,) * COVARIANCE


# -- reading ----------------------------------------------------------------------------------
def _time(r: CdrReader) -> TimeMsg:
    return TimeMsg(int(r.primitive("int32")), int(r.primitive("uint32")))


def _header(r: CdrReader) -> HeaderMsg:
    return HeaderMsg(_time(r), r.string())


def _floats(r: CdrReader, n: int) -> tuple[float, ...]:
    return tuple(float(r.primitive("float64")) for _ in range(n))


def _twist(r: CdrReader) -> TwistMsg:
    return TwistMsg(_floats(r, 3), _floats(r, 3))  # type: ignore[arg-type]


def _decoded(data: bytes | memoryview, what: str, read: Callable[[CdrReader], object]) -> object:
    reader = CdrReader(data, what)
    message = read(reader)
    reader.end()
    return message


def decode_laser_scan(data: bytes | memoryview) -> LaserScanMsg:
    def read(r: CdrReader) -> LaserScanMsg:
        header = _header(r)
        angles = [float(r.primitive("float32")) for _ in range(7)]
        return LaserScanMsg(header, *angles, r.float32_sequence(), r.float32_sequence())

    return _decoded(data, "sensor_msgs/LaserScan", read)  # type: ignore[return-value]


def decode_odometry(data: bytes | memoryview) -> OdometryMsg:
    def read(r: CdrReader) -> OdometryMsg:
        header, child = _header(r), r.string()
        position, orientation = _floats(r, 3), _floats(r, 4)
        pose_covariance = tuple(r.float64_array(COVARIANCE).tolist())
        twist = _twist(r)
        twist_covariance = tuple(r.float64_array(COVARIANCE).tolist())
        return OdometryMsg(
            header,
            child,
            position,  # type: ignore[arg-type]
            orientation,  # type: ignore[arg-type]
            pose_covariance,
            twist.linear,
            twist.angular,
            twist_covariance,
        )

    return _decoded(data, "nav_msgs/Odometry", read)  # type: ignore[return-value]


def decode_twist(data: bytes | memoryview) -> TwistMsg:
    return _decoded(data, "geometry_msgs/Twist", _twist)  # type: ignore[return-value]


def decode_twist_stamped(data: bytes | memoryview) -> TwistStampedMsg:
    def read(r: CdrReader) -> TwistStampedMsg:
        return TwistStampedMsg(_header(r), _twist(r))

    return _decoded(data, "geometry_msgs/TwistStamped", read)  # type: ignore[return-value]


# -- writing ----------------------------------------------------------------------------------
def _write_header(w: CdrWriter, header: HeaderMsg) -> None:
    w.primitive("int32", header.stamp.sec)
    w.primitive("uint32", header.stamp.nanosec)
    w.string(header.frame_id)


def _write_floats(w: CdrWriter, values: tuple[float, ...]) -> None:
    for value in values:
        w.primitive("float64", value)


def encode_twist(twist: TwistMsg, little_endian: bool = True) -> bytes:
    w = CdrWriter(little_endian)
    _write_floats(w, (*twist.linear, *twist.angular))
    return bytes(w)


def encode_twist_stamped(message: TwistStampedMsg, little_endian: bool = True) -> bytes:
    w = CdrWriter(little_endian)
    _write_header(w, message.header)
    _write_floats(w, (*message.twist.linear, *message.twist.angular))
    return bytes(w)


def encode_laser_scan(scan: LaserScanMsg, little_endian: bool = True) -> bytes:
    w = CdrWriter(little_endian)
    _write_header(w, scan.header)
    for value in (scan.angle_min, scan.angle_max, scan.angle_increment, scan.time_increment):
        w.primitive("float32", value)
    for value in (scan.scan_time, scan.range_min, scan.range_max):
        w.primitive("float32", value)
    w.float32_sequence(scan.ranges)
    w.float32_sequence(scan.intensities)
    return bytes(w)


def encode_odometry(odom: OdometryMsg, little_endian: bool = True) -> bytes:
    w = CdrWriter(little_endian)
    _write_header(w, odom.header)
    w.string(odom.child_frame_id)
    _write_floats(w, (*odom.position, *odom.orientation))
    w.float64_array(np.asarray(odom.pose_covariance), COVARIANCE)
    _write_floats(w, (*odom.linear, *odom.angular))
    w.float64_array(np.asarray(odom.twist_covariance), COVARIANCE)
    return bytes(w)


# -- the types, as rmw_zenoh names them -------------------------------------------------------
@dataclass(frozen=True)
class RosType:
    """A message type: `pkg/msg/Name`, its DDS name (rmw_zenoh's key and token) and hash."""

    name: str
    type_hash: str

    @property
    def dds_name(self) -> str:
        """`sensor_msgs::msg::dds_::LaserScan_`, as DDS and rmw_zenoh spell it."""
        package, kind, short = self.name.split("/")
        return f"{package}::{kind}::dds_::{short}_"


LASER_SCAN = RosType(
    "sensor_msgs/msg/LaserScan",
    "RIHS01_64c191398013af96509d518dac71d5164f9382553fce5c1f8cca5be7924bd828",
)
ODOMETRY = RosType(
    "nav_msgs/msg/Odometry",
    "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
)
TWIST = RosType(
    "geometry_msgs/msg/Twist",
    "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a",
)
TWIST_STAMPED = RosType(
    "geometry_msgs/msg/TwistStamped",
    "RIHS01_5f0fcd4f81d5d06ad9b4c4c63e3ea51b82d6ae4d0558f1d475229b1121db6f64",
)
ROS_TYPES = (LASER_SCAN, ODOMETRY, TWIST, TWIST_STAMPED)

"""The bridge's zenoh session to the robot: a client of the robot's router (rmw_zenohd, or a
DDS robot's zenoh-bridge-ros2dds), apart from the voxshape session's. Thin: it subscribes to
the scan and the odometry, decodes them in zenoh's thread and hands them to the node's loop;
it publishes the velocities, with rmw_zenoh's attachment and liveliness tokens (rmw.py).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import zenoh

from voxshape.services.ros2 import msgs
from voxshape.services.ros2.msgs import LaserScanMsg, OdometryMsg, RosType
from voxshape.services.ros2.rmw import (
    BEST_EFFORT,
    Attachment,
    AttachmentFormat,
    Qos,
    RmwError,
    RosNodeName,
    decode_attachment,
    encode_attachment,
    entity_gid,
    entity_token,
    fully_qualified,
    node_token,
    ros2dds_key,
    topic_key,
)
from voxshape.services.ros2.safety import Velocity

Mode = Literal["rmw_zenoh", "ros2dds"]
Cmd = Literal["twist", "twist_stamped"]
SCAN_QOS = Qos(reliability=BEST_EFFORT, depth=5)  # rclcpp's SensorDataQoS
RELIABLE_10 = Qos(depth=10)


@dataclass(frozen=True)
class LinkConfig:
    connect: tuple[str, ...]
    mode: Mode = "rmw_zenoh"
    domain: int = 0
    namespace: str = "/"
    scan_topic: str = "scan"
    odom_topic: str = "odom"
    cmd_topic: str = "cmd_vel"
    cmd: Cmd = "twist"
    attachment: Literal["auto", "33", "77"] = "auto"
    node_name: str = "voxshape_r1"
    connect_timeout: float = 10.0


@dataclass(frozen=True)
class RobotSample:
    """A scan or odometry message of the robot, decoded, and when it came (monotonic)."""

    topic: Literal["scan", "odom"]
    message: LaserScanMsg | OdometryMsg
    attachment: AttachmentFormat | None
    received: float


@dataclass(frozen=True)
class RobotProblem:
    """A sample of the robot's that could not be read."""

    topic: str
    problem: str


class RobotLink:
    def __init__(self, config: LinkConfig, deliver: Callable[[object], None]) -> None:
        self.config = config
        self.deliver = deliver
        conf = {
            "mode": "client",
            "connect": {
                "endpoints": list(config.connect),
                "timeout_ms": int(config.connect_timeout * 1000),
                "exit_on_failure": True,
            },
            "scouting": {"multicast": {"enabled": False}},
            "transport": {"shared_memory": {"enabled": False}},
        }
        self.session = zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))
        self.format: AttachmentFormat = "77" if config.attachment == "77" else "33"
        self.sequence = 0
        self.declared: list = []
        rmw = config.mode == "rmw_zenoh"
        name = RosNodeName(
            config.domain, str(self.session.zid()), config.node_name, config.namespace
        )
        self.cmd_type = msgs.TWIST_STAMPED if config.cmd == "twist_stamped" else msgs.TWIST
        self.keys = {
            topic: self._key(topic_name, ros_type)
            for topic, topic_name, ros_type in (
                ("scan", config.scan_topic, msgs.LASER_SCAN),
                ("odom", config.odom_topic, msgs.ODOMETRY),
                ("cmd", config.cmd_topic, self.cmd_type),
            )
        }
        for topic, decode in (("scan", msgs.decode_laser_scan), ("odom", msgs.decode_odometry)):
            self.declared.append(
                self.session.declare_subscriber(self.keys[topic], self._on_sample(topic, decode))
            )
        self.publisher = self.session.declare_publisher(
            self.keys["cmd"], congestion_control=zenoh.CongestionControl.BLOCK, express=True
        )
        self.declared.append(self.publisher)
        self.tokens = self._tokens(name) if rmw else {}
        cmd_token = self.tokens.get("cmd")
        self.gid = entity_gid(cmd_token or self.keys["cmd"])
        for token in self.tokens.values():
            self.declared.append(self.session.liveliness().declare_token(token))

    def _key(self, topic: str, ros_type: RosType) -> str:
        fqn = fully_qualified(self.config.namespace, topic)
        if self.config.mode == "ros2dds":
            return ros2dds_key(fqn)
        return topic_key(self.config.domain, fqn, ros_type)

    def _tokens(self, name: RosNodeName) -> dict[str, str]:
        """The node's and its entities' liveliness tokens: `ros2 node list` shows it."""
        c, ns = self.config, self.config.namespace
        return {
            "node": node_token(name),
            "scan": entity_token(
                name, 1, "MS", fully_qualified(ns, c.scan_topic), msgs.LASER_SCAN, SCAN_QOS
            ),
            "odom": entity_token(
                name, 2, "MS", fully_qualified(ns, c.odom_topic), msgs.ODOMETRY, RELIABLE_10
            ),
            "cmd": entity_token(
                name, 3, "MP", fully_qualified(ns, c.cmd_topic), self.cmd_type, RELIABLE_10
            ),
        }

    def _on_sample(self, topic: str, decode: Callable) -> Callable[[zenoh.Sample], None]:
        def on_sample(sample: zenoh.Sample) -> None:
            received = time.monotonic()
            try:
                fmt = None
                if sample.attachment is not None:
                    _, fmt = decode_attachment(sample.attachment.to_bytes())
                message = decode(sample.payload.to_bytes())
            except (ValueError, RmwError) as e:
                self.deliver(RobotProblem(topic, str(e)))
                return
            except Exception as e:  # never let a bad sample kill zenoh's callback thread
                self.deliver(RobotProblem(topic, repr(e)))
                return
            self.deliver(RobotSample(topic, message, fmt, received))  # type: ignore[arg-type]

        return on_sample

    def adopt(self, fmt: AttachmentFormat | None) -> bool:
        """With `--attachment auto`, the robot's own samples' format; True if it changed."""
        if self.config.attachment != "auto" or fmt is None or fmt == self.format:
            return False
        self.format = fmt
        return True

    def send(self, velocity: Velocity) -> None:
        v, omega = velocity
        twist = msgs.TwistMsg((v, 0.0, 0.0), (0.0, 0.0, omega))
        if self.cmd_type is msgs.TWIST_STAMPED:
            header = msgs.HeaderMsg(msgs.TimeMsg.of(time.time()), "base_link")
            payload = msgs.encode_twist_stamped(msgs.TwistStampedMsg(header, twist))
        else:
            payload = msgs.encode_twist(twist)
        attachment = None
        if self.config.mode == "rmw_zenoh":
            self.sequence += 1
            attachment = encode_attachment(
                Attachment(self.sequence, time.time_ns(), self.gid), self.format
            )
        self.publisher.put(payload, attachment=attachment)

    def connected(self) -> bool:
        return bool(self.session.info.routers_zid())

    def close(self) -> None:
        for declared in reversed(self.declared):
            declared.undeclare()
        self.session.close()

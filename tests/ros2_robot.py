"""A ROS 2 robot for tests, written against rmw_zenoh's design document (ros2/rmw_zenoh
docs/design.md) and the `rosbags` package, not against voxshape's bridge (it imports none of
voxshape/services/ros2): it plays the simulator's world (a map of voxshape/world), as a TurtleBot on
rmw_zenoh would show it.

- It is its own rmw_zenohd: a zenoh router listening on --listen, and a node (a peer
  session connected to it) publishing /scan (sensor_msgs/LaserScan, 360 beams, range 0.12 to
  3.5 m, inf beyond) and /odom (nav_msgs/Odometry) every 1/--hz robot seconds, each sample
  with rmw_zenoh's attachment (design.md: int64 LE sequence number, int64 LE source time in
  ns, a length byte and the 16-byte GID: 33 bytes; --attachment 77: the older format), and
  the liveliness tokens of its node, publishers and subscription.
- It drives by the cmd_vel (Twist, or TwistStamped with --cmd twist_stamped) it receives:
  a disk of --radius m whose pose integrates the last command and stays put where it would
  touch a wall (its odometry then stands still too; its scan never reads nearer than its
  radius). It stops by itself --cmd-timeout robot seconds after the last command (0.5 s, as
  diff_drive_controller's `cmd_vel_timeout`; 0: never, only the bridge stops it).
- --mast D: its lidar sees a part of itself D m away, behind (a mast, a handle).
- Its world runs at --rtf times real time when it can; a stall of its process slows its time
  down (as a loaded Gazebo's real-time factor drops) rather than skipping it forward in a burst
  of steps.
- Each cmd_vel it receives is checked (an attachment of the right size, its length byte,
  a sequence number one more than the last, a source time within 10 s of now) and printed as
  a JSON line: {"cmd": [v, w], "t": monotonic seconds, "attachment": "ok" or the problem};
  so is what it does by itself: {"contact": true|false, "t": ...} when its body starts or
  stops touching a wall (a command pushes it there), {"timeout": [v, w], "t": ...} when its
  command timeout stops it.
  A line "place" on stdin teleports it to its start pose, as a person carrying it would:
  odometry does not see it (wheels turned by hand see nothing); "mute" stops its scans and
  odometry (a driver that died). With --mode ros2dds it plays
  zenoh-bridge-ros2dds instead: plain keys, no attachment (and checks none comes).
"""

from __future__ import annotations

import argparse
import json
import math
import struct
import sys
import threading
import time

import numpy as np
import zenoh
from rosbags.typesys import Stores, get_typestore

from voxshape.world.maps import load_map

TYPES = get_typestore(Stores.ROS2_JAZZY)
RANGE_MIN, RANGE_MAX, BEAMS = 0.12, 3.5, 360
OFF = {
    "scouting": {"multicast": {"enabled": False}},
    "transport": {"shared_memory": {"enabled": False}},
}


def cmd_type(args: argparse.Namespace) -> str:
    stamped = args.cmd == "twist_stamped"
    return "geometry_msgs/msg/TwistStamped" if stamped else "geometry_msgs/msg/Twist"


def session(**conf: object) -> zenoh.Session:
    return zenoh.open(zenoh.Config.from_json5(json.dumps({**conf, **OFF})))


def dds(name: str) -> str:
    package, kind, short = name.split("/")
    return f"{package}::{kind}::dds_::{short}_"


def topic_key(args: argparse.Namespace, topic: str, typename: str) -> str:
    name = "/".join(p for p in (args.namespace.strip("/"), topic) if p)
    if args.mode == "ros2dds":
        return name
    return f"{args.domain}/{name}/{dds(typename)}/{TYPES.hash_rihs01(typename)}"


def cast(px: float, py: float, angles: np.ndarray, segments: np.ndarray, circles: np.ndarray):
    """Distance along each ray from (px, py) to the first wall or cylinder, inf if none."""
    dx, dy = np.cos(angles)[:, None], np.sin(angles)[:, None]
    best = np.full(len(angles), np.inf)
    if len(segments):
        ax, ay, bx, by = segments.T
        ex, ey = bx - ax, by - ay
        denom = dx * ey - dy * ex
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((ax - px) * ey - (ay - py) * ex) / denom
            u = ((ax - px) * dy - (ay - py) * dx) / denom
        best = np.minimum(best, np.where((t >= 0) & (u >= 0) & (u <= 1), t, np.inf).min(axis=1))
    if len(circles):
        cx, cy, r = circles.T
        b = (px - cx) * dx + (py - cy) * dy
        disc = b * b - ((px - cx) ** 2 + (py - cy) ** 2 - r * r)
        with np.errstate(invalid="ignore"):
            t = -b - np.sqrt(disc)
        best = np.minimum(best, np.where((disc >= 0) & (t >= 0), t, np.inf).min(axis=1))
    return best


class Robot:
    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.map = load_map(args.task)
        self.segments, self.circles = self.map.outlines()
        s = self.map.start
        self.start = (s.x, s.y, s.theta)
        self.pose = list(self.start)  # the truth: what the scan sees
        self.odom = list(self.start)  # what the wheels measured (odometry frame = the map's)
        self.cmd = (0.0, 0.0)
        self.since_cmd = 0.0  # robot seconds since the last command (--cmd-timeout)
        self.lock = threading.Lock()
        self.muted = False
        self.touching = False
        self.log = open(args.log, "a") if args.log else sys.stdout  # noqa: SIM115
        self.last_seq: dict[bytes, int] = {}  # per publisher GID, as rmw_zenoh counts

    def free(self, x: float, y: float) -> bool:
        return float(self.map.clearance(x, y)) >= self.args.radius

    def move(self, dt: float) -> None:
        with self.lock:
            lapsed = 0 < self.args.cmd_timeout < self.since_cmd
            if lapsed and self.cmd != (0.0, 0.0):
                self.say({"timeout": list(self.cmd)})
                self.cmd = (0.0, 0.0)
            v, w = self.cmd
            self.since_cmd += dt
            blocked = False
            for _ in range(4):
                x, y, th = self.pose
                th2 = th + w * dt / 4
                nx, ny = x + v * dt / 4 * math.cos(th), y + v * dt / 4 * math.sin(th)
                if not self.free(nx, ny):
                    nx, ny, blocked = x, y, True
                ox, oy, oth = self.odom
                self.odom = [ox + (nx - x), oy + (ny - y), oth + (th2 - th)]
                self.pose = [nx, ny, th2]
            if blocked != self.touching:
                self.touching = blocked
                self.say({"contact": blocked})

    def say(self, line: dict) -> None:
        print(json.dumps({**line, "t": time.monotonic()}), file=self.log, flush=True)

    def listen(self) -> None:
        """stdin: "place" teleports it to its start; "mute" stops its scans and odometry."""
        for line in sys.stdin:
            if line.strip() == "place":
                with self.lock:
                    self.pose = list(self.start)
            elif line.strip() == "mute":
                self.muted = True

    def check(self, sample: zenoh.Sample) -> str:
        """What is wrong with a cmd_vel sample's attachment, or "ok"."""
        raw = None if sample.attachment is None else sample.attachment.to_bytes()
        if self.args.mode == "ros2dds":
            return "ok" if raw is None else "an attachment zenoh-bridge-ros2dds does not use"
        size = 33 if self.args.attachment == "33" else 77
        if raw is None:
            return "no attachment: rmw_zenoh drops the sample"
        if len(raw) != size:
            return f"{len(raw)} bytes, not {size}"
        if size == 33:
            seq, stamp = struct.unpack_from("<qq", raw)
            length = raw[16]
        else:
            names = raw[0:16], raw[24:41], raw[49:60]
            if names != (b"\x0fsequence_number", b"\x10source_timestamp", b"\x0asource_gid"):
                return f"not the 77-byte layout: {names}"
            (seq,), (stamp,), length = (
                struct.unpack_from("<q", raw, 16),
                struct.unpack_from("<q", raw, 41),
                raw[60],
            )
        if length != 16:
            return f"GID length byte {length}, not 16"
        gid = raw[-16:]
        if gid in self.last_seq and seq != self.last_seq[gid] + 1:
            return f"sequence {seq} after {self.last_seq[gid]}"
        self.last_seq[gid] = seq
        if abs(stamp / 1e9 - time.time()) > 10:
            return f"source time {stamp} is not now"
        return "ok"

    def on_cmd(self, sample: zenoh.Sample) -> None:
        verdict = self.check(sample)
        message = TYPES.deserialize_cdr(sample.payload.to_bytes(), cmd_type(self.args))
        twist = message.twist if self.args.cmd == "twist_stamped" else message
        with self.lock:
            self.cmd = (float(twist.linear.x), float(twist.angular.z))
            self.since_cmd = 0.0
        line = {"cmd": list(self.cmd), "t": time.monotonic(), "attachment": verdict}
        print(json.dumps(line), file=self.log, flush=True)

    def scan(self, stamp: object) -> object:
        x, y, th = self.pose
        angles = th + np.arange(BEAMS) * (2 * math.pi / BEAMS)
        ranges = cast(x, y, angles, self.segments, self.circles)
        if self.args.mast:
            ranges[175:186] = np.minimum(ranges[175:186], self.args.mast)
        ranges = np.where(ranges > RANGE_MAX, np.inf, ranges).astype(np.float32)
        header = TYPES.types["std_msgs/msg/Header"](stamp=stamp, frame_id="base_scan")
        return TYPES.types["sensor_msgs/msg/LaserScan"](
            header=header,
            angle_min=0.0,
            angle_max=float(2 * math.pi * (BEAMS - 1) / BEAMS),
            angle_increment=float(2 * math.pi / BEAMS),
            time_increment=0.0,
            scan_time=1.0 / self.args.hz,
            range_min=RANGE_MIN,
            range_max=RANGE_MAX,
            ranges=ranges,
            intensities=np.zeros(0, np.float32),
        )

    def odometry(self, stamp: object) -> object:
        t = TYPES.types
        x, y, th = self.odom
        quaternion = t["geometry_msgs/msg/Quaternion"](0.0, 0.0, math.sin(th / 2), math.cos(th / 2))
        pose = t["geometry_msgs/msg/Pose"](t["geometry_msgs/msg/Point"](x, y, 0.0), quaternion)
        v, w = self.cmd
        twist = t["geometry_msgs/msg/Twist"](
            linear=t["geometry_msgs/msg/Vector3"](x=v, y=0.0, z=0.0),
            angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=w),
        )
        zeros = np.zeros(36)
        return t["nav_msgs/msg/Odometry"](
            header=t["std_msgs/msg/Header"](stamp=stamp, frame_id="odom"),
            child_frame_id="base_footprint",
            pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=zeros),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=zeros),
        )


def attachment(args: argparse.Namespace, seq: int, gid: bytes) -> bytes | None:
    """rmw_zenoh's attachment, as design.md lays it out (33 bytes), or the older 77."""
    if args.mode == "ros2dds":
        return None
    now = time.time_ns()
    if args.attachment == "33":
        return struct.pack("<qq", seq, now) + bytes([16]) + gid
    return (
        b"\x0fsequence_number" + struct.pack("<q", seq) + b"\x10source_timestamp"
        + struct.pack("<q", now) + b"\x0asource_gid" + bytes([16]) + gid
    )  # fmt: skip


def tokens(args: argparse.Namespace, zid: str) -> list[str]:
    """The node's, its publishers' and its subscription's liveliness tokens (design.md)."""
    ns = "%" + args.namespace.strip("/").replace("/", "%") if args.namespace.strip("/") else "%"
    base = f"@ros2_lv/{args.domain}/{zid}/0"
    prefix = ns if ns != "%" else ""
    out = [f"{base}/0/NN/%/{ns}/turtlebot"]
    for i, (kind, topic, typename, qos) in enumerate(
        (
            ("MP", "scan", "sensor_msgs/msg/LaserScan", "2::,5:,:,:,,"),
            ("MP", "odom", "nav_msgs/msg/Odometry", "::,10:,:,:,,"),
            ("MS", "cmd_vel", cmd_type(args), "::,10:,:,:,,"),
        ),
        start=10,
    ):
        name, type_hash = f"{prefix}%{topic}", TYPES.hash_rihs01(typename)
        out.append(f"{base}/{i}/{kind}/%/{ns}/turtlebot/{name}/{dds(typename)}/{type_hash}/{qos}")
    return out


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--listen", required=True)
    parser.add_argument("--mode", choices=("rmw_zenoh", "ros2dds"), default="rmw_zenoh")
    parser.add_argument("--domain", type=int, default=0)
    parser.add_argument("--namespace", default="/")
    parser.add_argument("--task", default="1")
    parser.add_argument("--rtf", type=float, default=1.0)
    parser.add_argument("--hz", type=float, default=10.0)
    parser.add_argument("--radius", type=float, default=0.2)
    parser.add_argument("--cmd", choices=("twist", "twist_stamped"), default="twist")
    parser.add_argument("--attachment", choices=("33", "77"), default="33")
    parser.add_argument("--log", help="write the cmd_vel lines to this file, not stdout")
    parser.add_argument("--cmd-timeout", type=float, default=0.5, help="robot s; 0: none")
    parser.add_argument("--mast", type=float, default=0.0, help="m: it sees itself there")
    args = parser.parse_args()
    router = session(mode="router", listen={"endpoints": [args.listen]})  # its rmw_zenohd
    node = session(
        mode="peer", connect={"endpoints": [args.listen]}, listen={"endpoints": ["tcp/127.0.0.1:0"]}
    )
    robot = Robot(args)
    held = [node.liveliness().declare_token(t) for t in tokens(args, str(node.zid()))]
    sub = node.declare_subscriber(topic_key(args, "cmd_vel", cmd_type(args)), robot.on_cmd)
    pubs = {
        "scan": node.declare_publisher(topic_key(args, "scan", "sensor_msgs/msg/LaserScan")),
        "odom": node.declare_publisher(topic_key(args, "odom", "nav_msgs/msg/Odometry")),
    }
    threading.Thread(target=robot.listen, daemon=True).start()
    print(json.dumps({"ready": args.listen}), flush=True)
    gids = {name: bytes(range(i, i + 16)) for i, name in enumerate(pubs)}
    period, seq, t0, robot_t = 1.0 / args.hz, 0, time.monotonic(), 0.0
    epoch = time.time()
    try:
        while True:
            robot.move(period)
            robot_t += period
            seq += 1
            whole = epoch + robot_t
            stamp = TYPES.types["builtin_interfaces/msg/Time"](int(whole), int(whole % 1 * 1e9))
            for name, message, typename in (
                ("odom", robot.odometry(stamp), "nav_msgs/msg/Odometry"),
                ("scan", robot.scan(stamp), "sensor_msgs/msg/LaserScan"),
            ):
                if robot.muted:
                    break
                payload = bytes(TYPES.serialize_cdr(message, typename))
                pubs[name].put(payload, attachment=attachment(args, seq, gids[name]))
            late = time.monotonic() - (t0 + robot_t / args.rtf)
            if late > period / args.rtf:  # stalled: its time slows down, no burst of steps
                t0 += late
            time.sleep(max(0.0, t0 + robot_t / args.rtf - time.monotonic()))
    except KeyboardInterrupt:
        pass
    finally:
        sub.undeclare()
        for token in held:
            token.undeclare()
        node.close()
        router.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())

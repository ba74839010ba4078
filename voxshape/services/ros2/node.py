"""`voxshape ros2`: a real ROS 2 robot in a voxshape session, as the simulator's robots are.

    voxshape ros2 --connect tcp/ROBOT:7447 --domain 0 --namespace / --goal 2,0
    voxshape ros2 --connect tcp/ROBOT:7447 --mode ros2dds --goal 2,0   (a DDS robot)

Two zenoh sessions: one a client of the robot's router (`--connect`: its rmw_zenohd, or its
zenoh-bridge-ros2dds), one on the voxshape session's bus (`--bus`, VOXSHAPE_CONNECT,
default tcp/127.0.0.1:7447). ROS traffic stays on the robot's side, voxshape's on its own
(with its own access control); the bridge is the one thing in both. docs/robot.md.

Robot side:  <domain>/<ns>/scan, <domain>/<ns>/odom in; <domain>/<ns>/cmd_vel out
Bus side (a teacher's placed: the robot is at its start again):

Its flows are its `ros2` row of voxshape/protocol/dataflow.py
(`voxshape dataflow --docstring ros2`).
"""

from __future__ import annotations

import argparse
import math
import os
import time

import zenoh

from voxshape.protocol import (
    Action,
    EpisodeEvent,
    Placed,
    RobotLimits,
    check_id,
)
from voxshape.runtime import (
    BusError,
    ConfigError,
    Input,
    Node,
    Output,
    Tick,
    add_bus_arguments,
    bus_config,
    fields,
    worth_logging,
)
from voxshape.services.ros2.bridge import Bridge, BridgeConfig, BridgeOutput, InsideRadius
from voxshape.services.ros2.contact import ContactConfig
from voxshape.services.ros2.episodes import EpisodeRules
from voxshape.services.ros2.homing import HomingConfig
from voxshape.services.ros2.rmw import RmwError, check_name
from voxshape.services.ros2.robot_link import LinkConfig, RobotLink, RobotProblem, RobotSample
from voxshape.services.ros2.safety import Limits
from voxshape.world.maps import add_task_argument, load_map
from voxshape.world.robot import CONTROL_PERIOD_S
from voxshape.world.task import Goal, steps_of

LOOP_TICK_S = 0.02  # wall seconds between checks of stops and steps due
BUS_CHECK_S = 0.1  # how often the link to the session's router is looked at
QUIET_WARN_S = 5.0  # a robot whose scan or odometry never came is named after this


def _pair(text: str, n: int, what: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != n:
        shape = ",".join("XYD"[:n]) if n == 3 else "X,Y"
        raise argparse.ArgumentTypeError(f"{what} {text!r}: expected {shape} (numbers)")
    return values


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser, {"connect": "--bus", "mode": "--bus-mode"})
    env = os.environ.get
    robot = parser.add_argument_group("the robot")
    robot.add_argument(
        "--connect",
        dest="robot_connect",
        required=True,
        help="the robot's zenoh router, comma-separated endpoints: its rmw_zenohd "
        "(tcp/ROBOT:7447) or, with --mode ros2dds, its zenoh-bridge-ros2dds",
    )
    robot.add_argument(
        "--mode",
        dest="ros_mode",
        choices=("rmw_zenoh", "ros2dds"),
        default="rmw_zenoh",
        help="how the robot's ROS 2 is reached: rmw_zenoh (its rmw_zenohd) or ros2dds (a DDS "
        "robot through zenoh-bridge-ros2dds) (default rmw_zenoh)",
    )
    robot.add_argument(
        "--domain",
        type=int,
        default=int(env("ROS_DOMAIN_ID") or 0),
        help="the robot's ROS_DOMAIN_ID (ROS_DOMAIN_ID; default 0)",
    )
    robot.add_argument(
        "--namespace", default="/", help="the robot's ROS namespace, e.g. /robot1 (default /)"
    )
    robot.add_argument(
        "--goal",
        required=True,
        type=lambda t: _pair(t, 2, "--goal"),
        help="X,Y: the goal in the robot's odometry frame, metres",
    )
    robot.add_argument(
        "--cmd",
        choices=("twist", "twist_stamped"),
        default="twist",
        help="cmd_vel's type: twist, or twist_stamped (Jazzy's diff_drive_controller) "
        "(default twist)",
    )
    _add_episodes(parser, robot)


def _add_episodes(parser: argparse.ArgumentParser, robot: argparse._ArgumentGroup) -> None:
    """The robot's id, task, limits, and what happens between its episodes."""
    env = os.environ.get
    robot.add_argument(
        "--robot",
        default=env("VOXSHAPE_ROBOT", "r1"),
        help="its id in the session (VOXSHAPE_ROBOT; default r1)",
    )
    add_task_argument(parser, "for the goal's radius and the timeout (and the page's map)")
    _add_limits(robot)
    robot.add_argument(
        "--reset",
        choices=("drive", "wait"),
        default="drive",
        help="between episodes: drive back to the start, or wait until a teacher says it is "
        "placed (default drive)",
    )
    robot.add_argument(
        "--homing-timeout",
        type=float,
        default=HomingConfig.timeout,
        help="robot s driving back to the start may take, then it waits to be placed "
        f"(default {HomingConfig.timeout:g})",
    )
    robot.add_argument(
        "--start",
        type=lambda t: _pair(t, 3, "--start"),
        help="X,Y,DEG in odometry (default: where it starts)",
    )
    robot.add_argument(
        "--rtf", type=float, default=1.0, help="a simulated robot's time factor (default 1)"
    )
    robot.add_argument(
        "--scan-yaw",
        type=float,
        default=0.0,
        help="degrees: where the scan's angle 0 points, left of the robot's heading (the "
        "lidar's mounting yaw; a TurtleBot 4's is 90, docs/robot.md#turtlebot-4) (default 0)",
    )
    robot.add_argument(
        "--attachment",
        choices=("auto", "33", "77"),
        default="auto",
        help="rmw_zenoh's attachment format: 33 bytes (rmw_zenoh 0.2.4 on) or 77 (before); "
        "auto: as the robot's (default auto)",
    )
    for topic in ("scan", "odom", "cmd"):
        name = "cmd_vel" if topic == "cmd" else topic
        robot.add_argument(f"--{topic}-topic", default=name, help=f"(default {name})")


def _add_limits(robot: argparse._ArgumentGroup) -> None:
    """What may move the robot: its bump, its limits, how long a command and its data last."""
    robot.add_argument(
        "--radius",
        type=float,
        default=0.2,
        help="m from the lidar: a scan reading nearer, in any direction, is a bump: the "
        "robot's own reach from its lidar plus a few cm (docs/robot.md#the-bump-radius; "
        "default 0.2; a TurtleBot 4: docs/robot.md#turtlebot-4)",
    )
    robot.add_argument(
        "--stuck-after",
        type=float,
        default=ContactConfig.stuck_after,
        help="robot s: told to move, its odometry nearly still this long, is a bump too "
        f"(default {ContactConfig.stuck_after:g})",
    )
    for flag, default, what in (
        ("--max-speed", Limits.max_speed, "m/s"),
        ("--max-turn", Limits.max_turn, "rad/s"),
        ("--action-timeout", Limits.action_timeout, "s a command stands"),
        ("--data-timeout", Limits.data_timeout, "s the robot's data may age"),
    ):
        robot.add_argument(flag, type=float, default=default, help=f"{what} (default {default:g})")


def configs(args: argparse.Namespace) -> tuple[BridgeConfig, LinkConfig]:
    """The bridge's and the link's settings from the flags (ConfigError naming a bad one)."""
    m = load_map(args.task)
    try:
        limits = Limits(args.max_speed, args.max_turn, args.action_timeout, args.data_timeout)
    except ValueError as e:
        raise ConfigError(str(e)) from None
    if min(args.rtf, args.radius, args.stuck_after, args.homing_timeout) <= 0 or args.domain < 0:
        raise ConfigError(
            "--rtf, --radius, --stuck-after and --homing-timeout must be > 0, --domain >= 0"
        )
    robot = check_id(args.robot, "robot")
    try:
        check_name(args.namespace, "--namespace")
        for topic in ("scan", "odom", "cmd"):
            check_name(getattr(args, f"{topic}_topic"), f"--{topic}-topic")
    except RmwError as e:
        raise ConfigError(str(e)) from None
    start = None
    if args.start is not None:
        x, y, degrees = args.start
        start = (x, y, math.radians(degrees))
    contact = ContactConfig(args.radius, args.stuck_after)
    goal = Goal(args.goal[0], args.goal[1], m.goal_radius)
    rules = EpisodeRules(goal, contact, steps_of(m.timeout, CONTROL_PERIOD_S))
    homing = HomingConfig(timeout=args.homing_timeout)
    yaw = math.radians(args.scan_yaw)
    bridge = BridgeConfig(
        rules, robot, args.reset, start, limits, homing, rtf=args.rtf, scan_yaw=yaw
    )
    connect = tuple(e.strip() for e in args.robot_connect.split(",") if e.strip())
    node_name = "voxshape_" + "".join(c if c.isalnum() else "_" for c in robot)
    link = LinkConfig(
        connect, args.ros_mode, args.domain, args.namespace, args.scan_topic, args.odom_topic,
        args.cmd_topic, args.cmd, args.attachment, node_name,
    )  # fmt: skip
    return bridge, link


def open_link(config: LinkConfig, node: Node) -> RobotLink:
    try:
        return RobotLink(config, node.deliver)
    except zenoh.ZError as e:
        raise BusError(
            f"cannot reach the robot's router at {', '.join(config.connect)}: "
            f"{str(e).split(' at ')[0]}. Is it running on the robot (`ros2 run rmw_zenoh_cpp "
            "rmw_zenohd`, or zenoh-bridge-ros2dds with --mode ros2dds), its port open, and "
            "--connect its address?"
        ) from None


def run(args: argparse.Namespace) -> int:
    bridge_config, link_config = configs(args)
    bus = bus_config("ros2", args, fail_fast=True)
    with Node("ros2", bus) as node:
        robot = bridge_config.robot
        outputs = {
            "obs": node.advertise("obs", robot),
            "episode": node.advertise("episode", robot),
        }
        limits = bridge_config.limits  # the learner fits its actions to them: none clipped
        node.publish(RobotLimits(robot=robot, max_speed=limits.max_speed, max_turn=limits.max_turn))
        node.subscribe("action", robot)
        node.subscribe("placed")
        link = open_link(link_config, node)
        bridge = Bridge(bridge_config, time.monotonic())
        node.log.info("bridging", extra=fields(robot=robot, **describe(link)))
        try:
            drive(node, link, bridge, outputs)
        except InsideRadius as e:
            raise ConfigError(f"not starting: {e}") from None
        finally:
            finish(node, link, bridge)
    return 0


def describe(link: RobotLink) -> dict[str, str]:
    c = link.config
    return {"mode": c.mode, "at": ",".join(c.connect), "scan": link.keys["scan"],
            "odom": link.keys["odom"], "cmd_vel": link.keys["cmd"]}  # fmt: skip


def drive(node: Node, link: RobotLink, bridge: Bridge, outputs: dict[str, Output]) -> None:
    """The loop: the robot's samples, the session's actions and placings, stops when due."""
    bus_ok, checked, started = True, 0.0, time.monotonic()
    heard: set[str] = set()
    for event in node.events(tick=LOOP_TICK_S):
        now = time.monotonic()
        out = BridgeOutput()
        match event:
            case RobotSample(topic="scan", message=scan, attachment=fmt):
                out = bridge.on_scan(scan, now)  # type: ignore[arg-type]
                if link.adopt(fmt):
                    node.log.info(
                        "cmd_vel's attachment follows the robot's", extra=fields(bytes=fmt)
                    )
                heard.add("scan")
            case RobotSample(topic="odom", message=odom):
                bridge.on_odom(odom, now)  # type: ignore[arg-type]
                heard.add("odom")
            case RobotProblem(topic=topic, problem=problem):
                node.counters[f"rejected.{topic}"] += 1
                if worth_logging(node.counters[f"rejected.{topic}"]):
                    node.log.warning(
                        "a robot's sample was not read", extra=fields(topic=topic, problem=problem)
                    )
            case Input(message=Action() as action):
                out = bridge.on_action(action, now)
            case Input(message=Placed() as placed):
                out = bridge.on_placed(placed, now)
            case Tick():
                if now - checked >= BUS_CHECK_S:
                    bus_ok, checked = bool(node.zenoh.info.routers_zid()), now
                out = bridge.tick(now, bus_ok)
                if heard != {"scan", "odom"} and now - started > QUIET_WARN_S:
                    started = float("inf")  # said once
                    missing = sorted({"scan", "odom"} - heard)
                    keys = ", ".join(link.keys[t] for t in missing)
                    node.log.warning(
                        f"nothing from the robot's {' and '.join(missing)} yet, on {keys}: check "
                        "`ros2 topic list` on the robot, --domain, --namespace, --mode, the topics"
                    )
        deliver(node, link, out, outputs)


def deliver(node: Node, link: RobotLink, out: BridgeOutput, outputs: dict[str, Output]) -> None:
    if out.velocity is not None:
        link.send(out.velocity)
    for message in out.messages:
        outputs["episode" if isinstance(message, EpisodeEvent) else "obs"].put(message)
    for note in out.notes:
        node.log.info(note)


def finish(node: Node, link: RobotLink, bridge: Bridge) -> None:
    """On exit: the robot stops (told a few times), then the link closes."""
    stop = bridge.shutdown(time.monotonic())
    for _ in range(3):
        if stop.velocity is not None:
            link.send(stop.velocity)
        time.sleep(0.01)
    node.log.info("stopped the robot", extra=fields(**bridge.counters, **bridge.safety.counters))
    link.close()

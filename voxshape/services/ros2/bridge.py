"""The bridge's core: a real robot's scans and odometry in, the simulator's messages out; the
learner's actions in, velocities for the robot out. Pure: decoded ROS messages and times in,
voxshape messages and velocities out (node.py puts it on the two buses).

Steps are due every control period: a step is taken on the first scan at or after its due
time (a fifth of a period early counts), so an observation leaves as soon as its scan
arrives; a late scan does not push the next ones back (_schedule). When scans come slower
than the control period, a step also comes half a period late with the latest scan. An
action is passed on as soon as it comes (safety.py decides what may move). Between
episodes the robot stops, then drives itself back to where its first episode started
(homing.py; `reset="drive"`) or waits until a teacher says it is placed there
(`reset="wait"`, also where homing gives up); a robot placed by hand has its odometry
re-anchored, so that it reads the start pose there.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from voxshape.protocol import Action, EpisodeEvent, Message, Placed
from voxshape.services.ros2.episodes import BridgePercept, EpisodeRules, Episodes
from voxshape.services.ros2.homing import HomingConfig, Pose3, homing_command
from voxshape.services.ros2.msgs import LaserScanMsg, OdometryMsg
from voxshape.services.ros2.perception import (
    Anchor,
    ScanGeometry,
    around_angles,
    around_from_scan,
    laser_from_scan,
    sonar_from_scan,
    yaw_of,
)
from voxshape.services.ros2.safety import Limits, Safety, Velocity
from voxshape.world.robot import CONTROL_PERIOD_S, RobotModel


class InsideRadius(ValueError):
    """The scan reads something inside the bump radius where the first episode would start."""


Reset = Literal["drive", "wait"]
State = Literal["waiting", "running", "homing", "placing"]
EARLY, LATE = 0.2, 0.5  # of a control period: a scan that may step, a step without a scan


@dataclass(frozen=True)
class BridgeConfig:
    rules: EpisodeRules
    robot: str = "r1"
    reset: Reset = "drive"
    start: Pose3 | None = None  # where episodes start, in odometry (None: where the first did)
    limits: Limits = field(default_factory=Limits)
    homing: HomingConfig = field(default_factory=HomingConfig)
    model: RobotModel = field(default_factory=RobotModel)
    control_period: float = CONTROL_PERIOD_S  # robot seconds
    rtf: float = 1.0  # robot seconds per wall second (a simulated robot may run faster)
    scan_yaw: float = 0.0  # radians: its scan frame's heading in its own (TurtleBot 4: pi/2)


@dataclass
class BridgeOutput:
    """What one input to the bridge gives: messages for the bus, a velocity for the robot,
    notes for the log."""

    messages: list[Message] = field(default_factory=list)
    velocity: Velocity | None = None  # to send to the robot now
    notes: list[str] = field(default_factory=list)  # for the log

    def add(self, other: BridgeOutput) -> BridgeOutput:
        self.messages += other.messages
        self.velocity = other.velocity if other.velocity is not None else self.velocity
        self.notes += other.notes
        return self


class Bridge:
    def __init__(self, config: BridgeConfig, now: float) -> None:
        self.config = config
        self.period = config.control_period / config.rtf  # wall seconds
        self.safety = Safety(config.limits, self.period)
        self.episodes = Episodes(config.robot, config.rules)
        self.counters: Counter[str] = Counter()
        self.t0 = now
        self.state: State = "waiting"
        self.scan: LaserScanMsg | None = None
        self.odom: OdometryMsg | None = None
        self.scan_at = self.odom_at = -math.inf
        self.next_due = -math.inf  # when the next step is due (wall seconds)
        self.fresh_scan = False  # a scan not yet stepped on
        self.anchor = Anchor()
        self.start = config.start
        self.bus_ok = True
        self.homing_since = 0.0  # on the robot's own clock (odometry_time)

    # -- inputs -------------------------------------------------------------------------------
    def robot_time(self, now: float) -> float:
        return (now - self.t0) * self.config.rtf

    def data_ok(self, now: float) -> bool:
        timeout = self.config.limits.data_timeout
        return now - self.scan_at <= timeout and now - self.odom_at <= timeout

    def on_odom(self, odom: OdometryMsg, now: float) -> None:
        self.odom, self.odom_at = odom, now

    def on_scan(self, scan: LaserScanMsg, now: float) -> BridgeOutput:
        self.scan, self.scan_at, self.fresh_scan = scan, now, True
        if now >= self.next_due - self.period * EARLY:
            return self._step(now)
        return BridgeOutput()

    def on_action(self, action: Action, now: float) -> BridgeOutput:
        why = self._refused(action)
        if why is not None:
            self.counters[f"actions.ignored.{why}"] += 1
            return BridgeOutput()
        assert action.v is not None and action.omega is not None
        self.counters["actions"] += 1
        fresh = self.bus_ok and self.data_ok(now)
        return BridgeOutput(velocity=self.safety.go(action.v, action.omega, now, fresh))

    def _refused(self, action: Action) -> str | None:
        if action.robot != self.config.robot:
            return "other_robot"
        if self.state != "running" or action.episode != self.episodes.episode:
            return "not_running"  # late: the episode it was for has ended
        if action.v is None or action.omega is None:
            return "no_velocity"
        return None

    def on_placed(self, placed: Placed, now: float) -> BridgeOutput:
        if placed.robot != self.config.robot or self.state not in ("homing", "placing"):
            self.counters["placed.ignored"] += 1
            return BridgeOutput()
        if self.odom is None or self.start is None:
            return BridgeOutput()
        self.anchor = Anchor.placing(self._odom_pose(), self.start)
        out = BridgeOutput(notes=[f"placed by {placed.teacher}: odometry re-anchored at the start"])
        return out.add(self._begin(now))

    def tick(self, now: float, bus_ok: bool) -> BridgeOutput:
        """Each period or sooner: a step due without a scan, stops due, homing commands."""
        self.bus_ok = bus_ok
        out = BridgeOutput()
        if self.fresh_scan is False and now >= self.next_due + self.period * LATE:
            out.add(self._step(now))
        fresh = bus_ok and self.data_ok(now)
        stop = self.safety.tick(now, fresh)
        if stop is not None and out.velocity is None:
            out.velocity = stop
        return out

    def shutdown(self, now: float) -> BridgeOutput:
        return BridgeOutput(
            velocity=self.safety.halt(now, "exit"), notes=["stopped the robot: exit"]
        )

    # -- steps ------------------------------------------------------------------------------------
    def _odom_pose(self) -> Pose3:
        assert self.odom is not None
        o = self.odom
        return o.position[0], o.position[1], yaw_of(*o.orientation)

    def percept(self) -> BridgePercept:
        assert self.scan is not None and self.odom is not None
        scan, model = self.scan, self.config.model
        geometry = ScanGeometry(  # its beams' angles in the robot's heading
            scan.angle_min + self.config.scan_yaw,
            scan.angle_increment,
            scan.range_min,
            scan.range_max,
        )
        x, y, theta = self.anchor.apply(*self._odom_pose())
        return BridgePercept(
            x,
            y,
            theta,
            self.odom.linear[0],
            self.odom.angular[2],
            laser_from_scan(scan.ranges, geometry, model),
            sonar_from_scan(scan.ranges, geometry, model),
            around_from_scan(scan.ranges, geometry),
        )

    def _step(self, now: float) -> BridgeOutput:
        if not self.data_ok(now):
            return BridgeOutput()
        self.fresh_scan = False
        self._schedule(now)
        if self.state == "waiting":
            return self._begin(now)
        if self.state == "running":
            return self._run(now)
        if self.state == "homing":
            return self._home(now)
        return BridgeOutput()

    def _schedule(self, now: float) -> None:
        """The next step's due time: a period after this one's (a late scan does not push the
        next ones back), re-anchored once scans lag behind it by 40% of a period (a lidar a
        little slower than the control period must not make steps of old scans)."""
        first = self.next_due == -math.inf
        self.next_due = (
            now + self.period
            if first
            else max(self.next_due + self.period, now + (1 - 2 * EARLY) * self.period)
        )

    def _begin(self, now: float) -> BridgeOutput:
        p = self.percept()
        notes = [f"episode {self.episodes.episode + 1} starts"]
        inside = self.inside_radius(p.around)
        if inside is not None and self.episodes.episode < 0:
            raise InsideRadius(inside)  # every step would be a bump: refuse, say why
        if inside is not None:
            self.counters["started_in_contact"] += 1
            notes.append(f"warning: {inside}")
        if self.start is None:
            self.start = (p.x, p.y, p.theta)
        self.state = "running"
        messages = self.episodes.start(p, self.robot_time(now))
        return BridgeOutput(messages=list(messages), notes=notes)

    def inside_radius(self, around: np.ndarray) -> str | None:
        """What is wrong when the scan reads something inside the bump radius where an
        episode would start (None when nothing is)."""
        radius = self.config.rules.contact.radius
        if not (np.nan_to_num(around, nan=np.inf) < radius).any():
            return None
        k = int(np.nanargmin(around))
        bearing = math.degrees(around_angles()[k])
        return (
            f"the scan reads {around[k]:.2f} m at {bearing:+.0f} deg (0 ahead, + left), inside "
            f"the bump radius ({radius:g} m), where an episode would start: each step would be "
            "a bump. Move the robot away from what it touches; if that is part of the robot "
            "(a mast, a bumper the lidar sees), give a --radius below that reading "
            "(docs/robot.md#the-bump-radius)"
        )

    def odometry_time(self, now: float) -> float:
        """When the odometry was measured, on the robot's own clock (its stamp): a robot whose
        process stalls moves nothing in its stamps' time either, so stuck is judged by them.
        Without stamps, the robot's time as the bridge reckons it."""
        assert self.odom is not None
        stamp = self.odom.header.stamp
        if stamp.sec or stamp.nanosec:
            return stamp.sec + stamp.nanosec * 1e-9
        return self.robot_time(now)

    def _run(self, now: float) -> BridgeOutput:
        speed = abs(self.safety.command[0])  # what the robot was told over the last step
        p = self.percept()
        messages: list[Message] = list(
            self.episodes.advance(p, self.robot_time(now), speed, self.odometry_time(now))
        )
        end = next((m for m in messages if isinstance(m, EpisodeEvent)), None)
        if end is None:
            return BridgeOutput(messages=messages)
        self.counters[f"episodes.{end.kind}"] += 1
        if self.episodes.bumped is not None:
            self.counters[f"bumps.{self.episodes.bumped}"] += 1
        out = BridgeOutput(messages, self.safety.halt(now, "episode"))
        if self.config.reset == "drive":
            self.state, self.homing_since = "homing", self.odometry_time(now)
            out.notes.append(f"episode {end.episode} ended ({end.kind}): driving back to the start")
        else:
            self.state = "placing"
            out.notes.append(f"episode {end.episode} ended ({end.kind}): {self.waits_for()}")
        return out

    def waits_for(self) -> str:
        robot = self.config.robot
        return (
            f"waiting for a teacher to place robot {robot} at its start (the page's "
            f"'placed' button, or `voxshape placed --robot {robot}`)"
        )

    def _home(self, now: float) -> BridgeOutput:
        assert self.start is not None
        p = self.percept()
        # the robot's own time: a simulated robot its machine slows down gets as long to drive
        if self.odometry_time(now) - self.homing_since > self.config.homing.timeout:
            self.state = "placing"
            self.counters["homing.gave_up"] += 1
            return BridgeOutput(
                velocity=self.safety.halt(now, "homing"),
                notes=[f"could not drive back to the start: {self.waits_for()}"],
            )
        v, omega, arrived = homing_command(
            (p.x, p.y, p.theta),
            self.start,
            p.around,
            self.config.rules.contact.radius,
            self.config.homing,
        )
        if arrived:
            self.counters["homing.arrived"] += 1
            out = BridgeOutput(velocity=self.safety.halt(now, "arrived"))
            return out.add(self._begin(now))
        return BridgeOutput(velocity=self.safety.go(v, omega, now, self.bus_ok))

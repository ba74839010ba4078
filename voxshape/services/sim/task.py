"""Episodes of a navigation task: the simulator's pure core (no bus).

`Simulation` steps every robot of one world at once, one control step of `control_period`
simulated seconds, and tells each robot's outcome by the task's rules (voxshape/world/rules.py,
which a real robot's bridge follows too). The service publishes what it returns; the
Gymnasium environment wraps it for single-robot RL; the experiments run it in-process.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from voxshape.runtime.settings import option
from voxshape.services.sim.sensors import Sensors
from voxshape.services.sim.world import World
from voxshape.world.maps import PASSAGE_RADIUS, ROBOT_CLEARANCE, Map, Pose
from voxshape.world.robot import CONTROL_PERIOD_S, RobotModel
from voxshape.world.rules import Outcome, Rewards, judge, steps_of

__all__ = ["Outcome", "Reading", "Rewards", "SimConfig", "Simulation"]  # the rules: world/rules.py


@dataclass(frozen=True)
class SimConfig:
    control_period: float = CONTROL_PERIOD_S  # simulated seconds per control step
    substeps: int = 4  # collision checks per control step
    # "continue" (as on the paper's robot): a bump costs the penalty and the robot stays put.
    # "end" also ends the episode; with -1 per step, crashing early then beats a long search
    # for a far goal, and plain SARSA(lambda) learns to crash (measured on tasks 2-4).
    collision: Literal["end", "continue"] = option(
        "continue", "a collision costs a penalty and goes on, or ends the episode"
    )
    timeout: float | None = None  # seconds of simulated time; None: the map's
    laser_noise: float = 0.0  # standard deviation of Gaussian range noise, metres
    sonar_noise: float = 0.0
    # Ranges beyond this many metres read as the sensor's maximum (None: full scans): for a
    # consumer that reads only near ranges, most ray casts are skipped (sensors.py).
    sensor_reach: float | None = None
    # A compiled ray cast (sensors.py), PyBullet asked about contacts only near something
    # (world.py). False: the reference path (numpy cast, a query at every sub-step), slower,
    # with the same results.
    fast: bool = True
    rewards: Rewards = field(default_factory=Rewards)
    model: RobotModel = field(default_factory=RobotModel)


@dataclass(frozen=True)
class Reading:
    """What one robot senses after a step or a reset."""

    robot: str
    episode: int
    step: int  # global step index of this robot, monotonic across episodes
    episode_step: int
    sim_time: float
    pose: Pose
    v: float
    omega: float
    laser: np.ndarray
    sonar: np.ndarray
    reward: float  # R_RL of the transition that led here (0 after a reset)
    goal_distance: float  # straight line to the goal's centre, metres
    goal_bearing: float  # to the goal's centre from the heading, radians (+ = left)
    episode_return: float
    outcome: Outcome
    collided: bool  # touched something during the last step

    # The pose as the learner reads it, like Observation's x, y and theta.
    @property
    def x(self) -> float:
        return self.pose.x

    @property
    def y(self) -> float:
        return self.pose.y

    @property
    def theta(self) -> float:
        return self.pose.theta


@dataclass
class _RobotProgress:
    """Where one simulated robot is: its episode and steps, return so far and velocity."""

    name: str
    index: int
    episode: int = -1
    step: int = -1
    episode_step: int = 0
    episode_return: float = 0.0
    v: float = 0.0
    omega: float = 0.0
    outcome: Outcome = "running"


class Simulation:
    def __init__(
        self,
        m: Map,
        robots: tuple[str, ...] = ("r1",),
        config: SimConfig | None = None,
        seed: int | None = None,
    ) -> None:
        if len(set(robots)) != len(robots) or not robots:
            raise ValueError(f"robot names must be distinct and at least one: {robots}")
        self.map = m
        self.config = config or SimConfig()
        c = self.config
        self.world = World(m, len(robots), c.model, c.substeps, cull=c.fast)
        self.sensors = Sensors(m, c.model, compiled=c.fast)
        self.robots = {name: _RobotProgress(name, i) for i, name in enumerate(robots)}
        self.rng = np.random.default_rng(seed)
        self.sim_time = 0.0
        self.max_episode_steps = steps_of(self.config.timeout or m.timeout, c.control_period)

    def seed(self, seed: int | None) -> None:
        self.rng = np.random.default_rng(seed)

    def reset(self, robot: str) -> Reading:
        """Starts a new episode for one robot at the map's start pose (jittered); if another
        robot stands there, at the nearest free place around it."""
        r = self.robots[robot]
        s, j = self.map.start, self.map.start_jitter
        jitter = self.rng.uniform(-1.0, 1.0, 3) * (j.x, j.y, j.theta)
        pose = Pose(
            float(s.x + jitter[0]),
            float(s.y + jitter[1]),
            math.remainder(float(s.theta + jitter[2]), math.tau),
        )
        self.world.place(r.index, pose)
        if len(self.robots) > 1 and self.world.in_contact(r.index):
            self.world.place(r.index, self._free_start_near(r.index, pose))
        r.episode += 1
        r.step += 1
        r.episode_step = 0
        r.episode_return = 0.0
        r.v = r.omega = 0.0
        r.outcome = "running"
        laser, sonar = self._sense()
        return self._reading(r, laser[r.index], sonar[r.index], 0.0, False)

    def _free_start_near(self, index: int, pose: Pose) -> Pose:
        """The first free pose on rings around `pose` (0.7 m apart, 16 places per ring) from
        which the goal is reachable."""
        m = self.map
        reachable = np.isfinite(m.grid.distances_to_goal(PASSAGE_RADIUS))
        for ring in range(1, 8):
            for k in range(16):
                a = pose.theta + k * math.tau / 16
                x = pose.x + 0.7 * ring * math.cos(a)
                y = pose.y + 0.7 * ring * math.sin(a)
                if not (0 < x < m.width and 0 < y < m.height):
                    continue
                if m.clearance(x, y) < ROBOT_CLEARANCE or not reachable[m.grid.cell(x, y)]:
                    continue
                self.world.place(index, Pose(x, y, pose.theta))
                if not self.world.in_contact(index):
                    return Pose(x, y, pose.theta)
        raise ValueError(
            f"no free start pose for {len(self.robots)} robots near the start of {m.name}: "
            "use fewer robots or a map with a larger start area"
        )

    def reset_all(self) -> dict[str, Reading]:
        readings = {name: self.reset(name) for name in self.robots}
        laser, sonar = self._sense()  # other robots may now stand in each other's view
        return {
            n: replace(rd, laser=laser[self.robots[n].index], sonar=sonar[self.robots[n].index])
            for n, rd in readings.items()
        }

    def step(self, commands: dict[str, tuple[float, float]]) -> dict[str, Reading]:
        """One control step of every robot. A robot without a command stops. Commands beyond
        the robot's limits are clipped (see `clip`). Robots whose episode ended must be reset
        first."""
        rewards = self.config.rewards
        dt = self.config.control_period
        collided = {}
        for name, r in self.robots.items():
            if r.outcome != "running":
                raise ValueError(f"robot {name}'s episode ended ({r.outcome}): reset it first")
            v, omega, _ = self.config.model.clip(*commands.get(name, (0.0, 0.0)))
            collided[name] = self.world.move(r.index, v, omega, dt)
            r.v, r.omega = (0.0, 0.0) if collided[name] else (v, omega)
        self.sim_time += dt
        laser, sonar = self._sense()
        readings = {}
        for name, r in self.robots.items():
            r.step += 1
            r.episode_step += 1
            pose = self.world.poses[r.index]
            reward, r.outcome = judge(
                rewards,
                bumped=collided[name],
                at_goal=bool(self.map.goal.contains(pose.x, pose.y)),
                episode_step=r.episode_step,
                max_steps=self.max_episode_steps,
                bump_ends=self.config.collision == "end",
            )
            r.episode_return += reward
            readings[name] = self._reading(
                r, laser[r.index], sonar[r.index], reward, collided[name]
            )
        return readings

    def _sense(self) -> tuple[np.ndarray, np.ndarray]:
        laser, sonar = self.sensors.scan(self.world.poses, self.config.sensor_reach)
        m, c = self.config.model, self.config
        if c.laser_noise > 0:
            laser = np.clip(
                laser + self.rng.normal(0, c.laser_noise, laser.shape), m.laser_min, m.laser_max
            )
        if c.sonar_noise > 0:
            sonar = np.clip(
                sonar + self.rng.normal(0, c.sonar_noise, sonar.shape), m.sonar_min, m.sonar_max
            )
        return laser, sonar

    def _reading(
        self, r: _RobotProgress, laser: np.ndarray, sonar: np.ndarray, reward: float, collided: bool
    ) -> Reading:
        pose = self.world.poses[r.index]
        distance, bearing = self.map.goal.seen_from(pose.x, pose.y, pose.theta)
        return Reading(
            robot=r.name,
            episode=r.episode,
            step=r.step,
            episode_step=r.episode_step,
            sim_time=self.sim_time,
            pose=pose,
            v=r.v,
            omega=r.omega,
            laser=laser,
            sonar=sonar,
            reward=reward,
            goal_distance=distance,
            goal_bearing=bearing,
            episode_return=r.episode_return,
            outcome=r.outcome,
            collided=collided,
        )

    def close(self) -> None:
        self.world.close()

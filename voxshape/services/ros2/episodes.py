"""A real robot's episodes, told as the simulator tells them: a step's observation with R_RL
and the episode's outcome, and the start and end events. Pure.

The rules are the task's, the simulator's own (voxshape/world/rules.py): an episode ends at the
goal (the robot's odometry within the task's goal radius), at a bump or when it has lasted
the task's timeout in control steps; -1 a step, +100 at the goal, -100 for a bump. A bump
ends the episode (a real robot must not push on); what a bump is, all round, is contact.py's.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from voxshape.protocol import EpisodeEvent, Observation
from voxshape.services.ros2.contact import Contact, ContactConfig
from voxshape.world.rules import Goal, Outcome, Rewards, judge

SPEED_BOUND, TURN_BOUND = 10.0, 20.0  # Observation's bounds on v and omega


@dataclass(frozen=True)
class BridgePercept:
    """One step's senses of the real robot, in the task's frame (what the bridge makes of its
    scan and odometry)."""

    x: float
    y: float
    theta: float
    v: float
    omega: float
    laser: np.ndarray
    sonar: np.ndarray
    around: np.ndarray  # the nearest reading all round (perception.around_from_scan)


@dataclass(frozen=True)
class EpisodeRules:
    goal: Goal  # in the robot's odometry frame
    contact: ContactConfig
    max_steps: int  # the timeout, in control steps
    rewards: Rewards = field(default_factory=Rewards)


class Episodes:
    """Counts one robot's episodes and steps; turns percepts into its messages."""

    def __init__(self, robot: str, rules: EpisodeRules) -> None:
        self.robot = robot
        self.rules = rules
        self.contact = Contact(rules.contact)
        self.episode = -1
        self.step = -1  # global, monotonic across episodes (the simulator's)
        self.episode_step = 0
        self.episode_return = 0.0
        self.running = False
        self.bumped: str | None = None  # what the last step's bump was: "scan", "stuck"

    def start(self, p: BridgePercept, robot_time: float) -> list[EpisodeEvent | Observation]:
        """A new episode from where the robot stands: its start event and first observation."""
        self.episode += 1
        self.step += 1
        self.episode_step = 0
        self.episode_return = 0.0
        self.running = True
        self.contact.reset()
        event = self._event("start", robot_time)
        return [event, self._observation(p, 0.0, "running", False, robot_time)]

    def advance(
        self,
        p: BridgePercept,
        robot_time: float,
        speed: float = 0.0,
        measured_at: float | None = None,
    ) -> list[EpisodeEvent | Observation]:
        """One control step (`speed`: the |v| the robot was told over it; `measured_at`: when
        its odometry was taken, on the robot's clock, default `robot_time`): its observation,
        and the end event if the episode ended."""
        assert self.running, "start() an episode first"
        rules = self.rules
        self.step += 1
        self.episode_step += 1
        at = robot_time if measured_at is None else measured_at
        self.bumped = self.contact.touching(p.around, at, p.x, p.y, speed)
        reward, outcome = judge(
            rules.rewards,
            bumped=self.bumped is not None,
            at_goal=bool(rules.goal.contains(p.x, p.y)),
            episode_step=self.episode_step,
            max_steps=rules.max_steps,
        )
        self.episode_return += reward
        out: list[EpisodeEvent | Observation] = [
            self._observation(p, reward, outcome, self.bumped is not None, robot_time)
        ]
        if outcome != "running":
            self.running = False
            out.append(self._event(outcome, robot_time))
        return out

    def _observation(
        self, p: BridgePercept, reward: float, outcome: Outcome, collided: bool, robot_time: float
    ) -> Observation:
        distance, bearing = self.rules.goal.seen_from(p.x, p.y, p.theta)
        return Observation(
            robot=self.robot,
            episode=self.episode,
            step=self.step,
            episode_step=self.episode_step,
            sim_time=robot_time,
            wall_time=time.time(),
            x=p.x,
            y=p.y,
            theta=math.remainder(p.theta, math.tau),
            v=min(max(p.v, -SPEED_BOUND), SPEED_BOUND),
            omega=min(max(p.omega, -TURN_BOUND), TURN_BOUND),
            laser=tuple(p.laser.tolist()),
            sonar=tuple(p.sonar.tolist()),
            reward=reward,
            goal_distance=distance,
            goal_bearing=bearing,
            outcome=outcome,
            collided=collided,
        )

    def _event(self, kind: str, robot_time: float) -> EpisodeEvent:
        return EpisodeEvent(
            robot=self.robot,
            episode=self.episode,
            step=self.step,
            kind=kind,  # type: ignore[arg-type]
            episode_steps=self.episode_step,
            sim_time=robot_time,
            wall_time=time.time(),
            env_return=self.episode_return,
        )

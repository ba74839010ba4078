"""A real robot's episodes, told as the simulator tells them (services/sim/task.py): a step's
observation with R_RL and the episode's outcome, and the start and end events. Pure.

An episode ends at the goal (the robot's odometry within the task's goal radius), at a bump
(the scan's nearest beam under the robot's radius: a real robot must not push on) or when
it has lasted the task's timeout, counted in control steps as the simulator counts it. The
rewards are the simulator's (services/sim/task.py Rewards, which tests compare): -1 a step,
+100 at the goal, -100 for a bump.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from protocol import EpisodeEvent, Observation

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


@dataclass(frozen=True)
class EpisodeRules:
    goal_x: float
    goal_y: float
    goal_radius: float
    bump_radius: float  # metres from the robot's centre
    max_steps: int  # the timeout, in control steps
    step_reward: float = -1.0
    goal_reward: float = 100.0
    bump_reward: float = -100.0


class Episodes:
    """Counts one robot's episodes and steps; turns percepts into its messages."""

    def __init__(self, robot: str, rules: EpisodeRules) -> None:
        self.robot = robot
        self.rules = rules
        self.episode = -1
        self.step = -1  # global, monotonic across episodes (the simulator's)
        self.episode_step = 0
        self.episode_return = 0.0
        self.running = False

    def start(self, p: BridgePercept, robot_time: float) -> list[EpisodeEvent | Observation]:
        """A new episode from where the robot stands: its start event and first observation."""
        self.episode += 1
        self.step += 1
        self.episode_step = 0
        self.episode_return = 0.0
        self.running = True
        event = self._event("start", robot_time)
        return [event, self._observation(p, 0.0, "running", False, robot_time)]

    def advance(self, p: BridgePercept, robot_time: float) -> list[EpisodeEvent | Observation]:
        """One control step: its observation, and the end event if the episode ended."""
        assert self.running, "start() an episode first"
        rules = self.rules
        self.step += 1
        self.episode_step += 1
        reward = rules.step_reward
        bumped = bool(len(p.laser)) and float(np.min(p.laser)) < rules.bump_radius
        outcome = "running"
        if bumped:
            reward += rules.bump_reward
            outcome = "collision"
        elif math.hypot(p.x - rules.goal_x, p.y - rules.goal_y) <= rules.goal_radius:
            reward += rules.goal_reward
            outcome = "goal"
        elif self.episode_step >= rules.max_steps:
            outcome = "timeout"
        self.episode_return += reward
        out: list[EpisodeEvent | Observation] = [
            self._observation(p, reward, outcome, bumped, robot_time)
        ]
        if outcome != "running":
            self.running = False
            out.append(self._event(outcome, robot_time))
        return out

    def _observation(
        self, p: BridgePercept, reward: float, outcome: str, collided: bool, robot_time: float
    ) -> Observation:
        r = self.rules
        dx, dy = r.goal_x - p.x, r.goal_y - p.y
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
            goal_distance=math.hypot(dx, dy),
            goal_bearing=math.remainder(math.atan2(dy, dx) - p.theta, math.tau),
            outcome=outcome,  # type: ignore[arg-type]
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

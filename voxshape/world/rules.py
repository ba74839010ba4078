"""A navigation task's rules, written once: the environment's reward R_RL, how an episode
ends, and where the goal lies as the robot sees it. The simulator (voxshape/services/sim/task.py,
and through it the Gymnasium environment and the in-process experiments) and a real robot's bridge
(voxshape/services/ros2/episodes.py) both judge their steps here, so they cannot drift apart. Pure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

Outcome = Literal["running", "goal", "collision", "timeout"]


@dataclass(frozen=True)
class Rewards:
    """R_RL, the environment's own reward. The paper's learner uses R = R_RL + R_U, where R_U
    comes from the teachers (see the arbiter)."""

    step: float = -1.0  # every control step, so shorter paths are better
    goal: float = 100.0  # reaching the goal region; ends the episode
    collision: float = -100.0  # touching a wall, obstacle or another robot
    # A timeout adds nothing: the episode is cut short (truncated), not failed.


@dataclass(frozen=True)
class Goal:
    """The goal region: a disc of `radius` metres around (x, y), in the robot's frame of
    positions (the map's, or a real robot's odometry)."""

    x: float
    y: float
    radius: float

    def contains(self, x: ArrayLike, y: ArrayLike) -> bool | np.ndarray:
        """Whether a position (or each of arrays of them) lies in the goal region."""
        return np.hypot(np.subtract(x, self.x), np.subtract(y, self.y)) <= self.radius

    def seen_from(self, x: float, y: float, theta: float) -> tuple[float, float]:
        """The straight-line distance to the goal's centre and its bearing from the heading
        (radians, + = to the left), as observations carry them."""
        dx, dy = self.x - x, self.y - y
        return math.hypot(dx, dy), math.remainder(math.atan2(dy, dx) - theta, math.tau)


def steps_of(timeout_s: float, control_period: float) -> int:
    """An episode's timeout in control steps (at least one)."""
    return max(1, round(timeout_s / control_period))


def judge(
    rewards: Rewards,
    *,
    bumped: bool,
    at_goal: bool,
    episode_step: int,
    max_steps: int,
    bump_ends: bool = True,
) -> tuple[float, Outcome]:
    """A step's R_RL and how the episode stands after it: a bump costs the collision reward
    and ends the episode (unless `bump_ends` is False: the paper's robot goes on), then the
    goal, then the timeout (`episode_step` counts this step)."""
    reward, outcome = rewards.step, "running"
    if bumped:
        reward += rewards.collision
        if bump_ends:
            outcome = "collision"
    if outcome == "running" and at_goal:
        reward += rewards.goal
        outcome = "goal"
    if outcome == "running" and episode_step >= max_steps:
        outcome = "timeout"
    return reward, outcome  # type: ignore[return-value]

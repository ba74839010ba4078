"""Where each action would take the robot in the next moment, as far as its laser says it can go.

The policy's lookahead (sarsa.py `_expected_progress`) ranks actions by the potential's rise
from here to there. Each action's arc is followed in short steps; the first step whose place
lies within ROOM of something the laser shows ends it, so an action into a wall promises no
progress and the robot does not press on against it."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from voxshape.world.robot import RobotModel, unicycle

STEPS = 10  # samples along each arc
ROBOT = RobotModel()
ANGLES = ROBOT.laser_angles()
ROOM = ROBOT.length / 2 + 0.05  # metres from the robot's centre to what it must not touch


def reachable(
    pose: tuple[float, float, float],
    laser: Sequence[float] | np.ndarray,
    velocities: np.ndarray,
    seconds: float,
) -> list[tuple[float, float]]:
    """The place each (v, omega) of `velocities` leads to within `seconds`, stopped short of
    what the laser (beams over ANGLES, right to left) shows in the way."""
    x, y, theta = pose
    seen = _obstacles(laser)
    c, s = math.cos(theta), math.sin(theta)
    places = []
    for v, omega in velocities:
        dx, dy = 0.0, 0.0
        for i in range(1, STEPS + 1):
            ax, ay, _ = unicycle(0.0, 0.0, 0.0, v, omega, seconds * i / STEPS)
            if len(seen) and np.min(np.hypot(seen[:, 0] - ax, seen[:, 1] - ay)) < ROOM:
                break
            dx, dy = ax, ay
        places.append((x + c * dx - s * dy, y + s * dx + c * dy))
    return places


def reach(velocities: np.ndarray, seconds: float) -> float:
    """How far the laser must see for the lookahead: the farthest an arc goes from it, and
    ROOM."""
    return float(np.max(np.abs(velocities[:, 0]))) * seconds + ROBOT.laser_x + ROOM


def _obstacles(laser: Sequence[float] | np.ndarray) -> np.ndarray:
    """The laser's readings as points (n, 2) in the robot's frame (none if its layout is
    another than the robot model's)."""
    ranges = np.asarray(laser, dtype=float)
    if len(ranges) != len(ANGLES):
        return np.zeros((0, 2))
    hit = ranges < ROBOT.laser_max
    r, a = ranges[hit], ANGLES[hit]
    return np.stack([ROBOT.laser_x + r * np.cos(a), r * np.sin(a)], axis=1)

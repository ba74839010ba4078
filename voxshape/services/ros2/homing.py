"""Driving a real robot back to its start pose between episodes, around what its scan shows.
Pure: a pose and the scan's nearest readings all round in, a velocity out.

A small reactive controller, enough for a room: it turns towards the start and drives there,
slowing near it; with something ahead within `clearance` it turns in place to the side with
more room. Nearer than the robot's radius ahead, it backs off a little, but only when the
scan shows the way behind clear (else it turns in place): it never drives into what the scan
shows, ahead or behind. At the start it turns to the start heading. It gives up after
`timeout` robot seconds (a room it cannot find its way in): then a teacher places the robot
(voxshape/services/ros2/bridge.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from voxshape.services.ros2.perception import around_angles

Pose3 = tuple[float, float, float]
BEHIND = math.radians(150)  # the sector behind: |bearing| beyond this
ANGLES = around_angles()


@dataclass(frozen=True)
class HomingConfig:
    speed: float = 0.2  # m/s at most
    turn: float = 0.8  # rad/s at most
    position_tolerance: float = 0.15  # m
    heading_tolerance: float = math.radians(10)
    clearance: float = 0.45  # m ahead it wants free before driving on
    backing: float = 0.15  # m behind, beyond the robot's radius, it wants free to back off
    timeout: float = 120.0  # robot seconds


def _sector_min(around: np.ndarray, lo: float, hi: float) -> float:
    """The nearest reading between bearings lo and hi (radians, within [-pi, pi]); inf where
    the scan shows nothing, NaN where it does not look at all."""
    angles = ANGLES
    inside = around[(angles >= lo) & (angles <= hi)]
    seen = inside[~np.isnan(inside)]
    return float(seen.min()) if len(seen) else math.nan


def _free(distance: float, wanted: float) -> bool:
    """Whether a sector's nearest reading leaves `wanted` metres (an unseen sector never does)."""
    return not math.isnan(distance) and distance >= wanted


def homing_command(
    pose: Pose3,
    start: Pose3,
    around: np.ndarray,
    radius: float,
    config: HomingConfig = HomingConfig(),
) -> tuple[float, float, bool]:
    """(v, omega, arrived): the next command on the way to `start`; arrived when there, in
    its heading (then the command is a stop). `around`: the scan's nearest readings all round
    (perception.around_from_scan); `radius`: the robot's bump radius."""
    x, y, theta = pose
    distance = math.hypot(start[0] - x, start[1] - y)
    if distance <= config.position_tolerance:
        error = math.remainder(start[2] - theta, math.tau)
        if abs(error) <= config.heading_tolerance:
            return 0.0, 0.0, True
        return 0.0, math.copysign(min(config.turn, 1.5 * abs(error) + 0.1), error), False
    error = math.remainder(math.atan2(start[1] - y, start[0] - x) - theta, math.tau)
    ahead = _sector_min(around, -math.radians(30), math.radians(30))
    left = _sector_min(around, 0.0, math.pi / 2)
    right = _sector_min(around, -math.pi / 2, 0.0)
    aside = config.turn if _room(left) >= _room(right) else -config.turn
    if not _free(ahead, radius):  # too close ahead (or blind): back off if the way is free
        behind = min(_sector_min(around, BEHIND, math.pi), _sector_min(around, -math.pi, -BEHIND))
        if _free(behind, radius + config.backing):
            return -0.5 * config.speed, 0.0, False
        return 0.0, aside, False
    if abs(error) > 0.5:
        # Turn towards the start, unless what it turned away from lies that way and the way
        # ahead is free: then on ahead (along the obstacle). It never drives into one.
        lo, hi = sorted((0.0, math.copysign(min(abs(error), math.pi / 2), error)))
        if _free(ahead, config.clearance) and not _free(
            _sector_min(around, lo, hi), config.clearance
        ):
            return 0.5 * config.speed, 0.0, False
        return 0.0, math.copysign(config.turn, error), False
    if not _free(ahead, config.clearance):  # facing the start, something in the way: turn aside
        return 0.0, aside, False
    v = min(config.speed, 0.8 * distance + 0.05)
    return v, max(-config.turn, min(config.turn, 1.5 * error)), False


def _room(distance: float) -> float:
    """A sector's room to turn towards: none where the scan does not look."""
    return -1.0 if math.isnan(distance) else distance

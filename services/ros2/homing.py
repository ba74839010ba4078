"""Driving a real robot back to its start pose between episodes, around what its laser sees.
Pure: a pose and a laser in, a velocity out.

A small reactive controller, enough for a room: it turns towards the start and drives there,
slowing near it; with something ahead within `clearance` it turns in place to the side with
more room (and backs off a little when it is nearer than the robot's radius); at the start it
turns to the start heading. It gives up after `timeout` robot seconds (a room it cannot
find its way in): then a teacher places the robot (services/ros2/bridge.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from services.world.robot import RobotModel

Pose3 = tuple[float, float, float]


@dataclass(frozen=True)
class HomingConfig:
    speed: float = 0.2  # m/s at most
    turn: float = 0.8  # rad/s at most
    position_tolerance: float = 0.15  # m
    heading_tolerance: float = math.radians(10)
    clearance: float = 0.45  # m ahead it wants free before driving on
    timeout: float = 120.0  # robot seconds


def _sector_min(laser: np.ndarray, model: RobotModel, lo: float, hi: float) -> float:
    angles = model.laser_angles()
    inside = (angles >= lo) & (angles <= hi)
    return float(laser[inside].min()) if inside.any() else model.laser_max


def homing_command(
    pose: Pose3,
    start: Pose3,
    laser: np.ndarray,
    model: RobotModel,
    radius: float,
    config: HomingConfig = HomingConfig(),
) -> tuple[float, float, bool]:
    """(v, omega, arrived): the next command on the way to `start`; arrived when there, in
    its heading (then the command is a stop)."""
    x, y, theta = pose
    distance = math.hypot(start[0] - x, start[1] - y)
    if distance <= config.position_tolerance:
        error = math.remainder(start[2] - theta, math.tau)
        if abs(error) <= config.heading_tolerance:
            return 0.0, 0.0, True
        return 0.0, math.copysign(min(config.turn, 1.5 * abs(error) + 0.1), error), False
    error = math.remainder(math.atan2(start[1] - y, start[0] - x) - theta, math.tau)
    ahead = _sector_min(laser, model, -math.radians(30), math.radians(30))
    if ahead < radius:
        return -0.5 * config.speed, 0.0, False  # too close: back off
    if abs(error) > 0.5:
        # Turn towards the start, unless what it turned away from lies that way and the way
        # ahead is free: then on ahead (along the obstacle). It never drives into one.
        lo, hi = sorted((0.0, math.copysign(min(abs(error), math.pi / 2), error)))
        if ahead >= config.clearance and _sector_min(laser, model, lo, hi) < config.clearance:
            return 0.5 * config.speed, 0.0, False
        return 0.0, math.copysign(config.turn, error), False
    if ahead < config.clearance:  # facing the start, something in the way: turn aside
        left = _sector_min(laser, model, 0.0, math.pi / 2)
        right = _sector_min(laser, model, -math.pi / 2, 0.0)
        return 0.0, config.turn if left >= right else -config.turn, False
    v = min(config.speed, 0.8 * distance + 0.05)
    return v, max(-config.turn, min(config.turn, 1.5 * error)), False

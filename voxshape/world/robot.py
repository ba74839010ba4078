"""The robot: a Pioneer 2 DX as far as navigation cares (footprint, limits, sensor layout)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

CONTROL_PERIOD_S = 0.1  # seconds per control step: the robot is driven at 10 Hz


def unicycle(
    x: float, y: float, theta: float, v: float, omega: float, seconds: float
) -> tuple[float, float, float]:
    """The exact pose of a differential robot after `seconds` at (v, omega)."""
    if abs(omega) < 1e-9:
        return x + v * seconds * math.cos(theta), y + v * seconds * math.sin(theta), theta
    turned = theta + omega * seconds
    return (
        x + v / omega * (math.sin(turned) - math.sin(theta)),
        y - v / omega * (math.cos(turned) - math.cos(theta)),
        math.remainder(turned, math.tau),
    )


@dataclass(frozen=True)
class RobotModel:
    length: float = 0.45  # metres, along the heading
    width: float = 0.38
    max_speed: float = 0.7  # m/s
    max_turn: float = math.radians(100)  # rad/s
    laser_beams: int = 180
    laser_fov: float = math.pi  # the beams span this, centred ahead
    laser_min: float = 0.02
    laser_max: float = 8.0
    laser_x: float = 0.15  # the laser sits this far ahead of the centre
    sonar_angles: tuple[float, ...] = tuple(
        math.radians(a) for a in (90, 130, 150, 170, -170, -150, -130, -90)
    )  # the rear ring, from the left side round the back to the right side
    sonar_cone: float = math.radians(15)
    sonar_rays: int = 3  # rays sampling each cone
    sonar_min: float = 0.1
    sonar_max: float = 5.0
    # The bumper reflex: metres the robot backs off from a bump, room for an arc to turn away
    # (the learner's arcs turn on a radius of 0.29 m); with less, an arc meets the wall again
    # and a robot whose every action moves forward is pinned there (docs/decisions.md).
    recoil: float = 0.3

    @property
    def circumradius(self) -> float:
        """The farthest a point of the footprint lies from its centre."""
        return math.hypot(self.length / 2, self.width / 2)

    def laser_angles(self) -> np.ndarray:
        """Beam directions in the robot frame, evenly spread over the field of view."""
        step = self.laser_fov / self.laser_beams
        return -self.laser_fov / 2 + step * (np.arange(self.laser_beams) + 0.5)

    def sonar_ray_angles(self) -> np.ndarray:
        """(sonars, rays) directions sampling each sonar's cone."""
        offsets = np.linspace(-self.sonar_cone / 2, self.sonar_cone / 2, self.sonar_rays)
        return np.array(self.sonar_angles)[:, None] + offsets[None, :]

    def surface_distance(self, angles: np.ndarray) -> np.ndarray:
        """Distance from the centre to the edge of the footprint along each angle."""
        c, s = np.abs(np.cos(angles)), np.abs(np.sin(angles))
        with np.errstate(divide="ignore"):
            return np.minimum(self.length / 2 / c, self.width / 2 / s)

    def clip(self, v: float, omega: float) -> tuple[float, float, bool]:
        """The command within the robot's limits, and whether it had to be clipped."""
        cv = min(max(v, -self.max_speed), self.max_speed)
        co = min(max(omega, -self.max_turn), self.max_turn)
        return cv, co, (cv, co) != (v, omega)

    def corners(self, x: float, y: float, theta: float) -> np.ndarray:
        """The footprint's corners (4, 2) at a pose, counter-clockwise."""
        c, s = math.cos(theta), math.sin(theta)
        hl, hw = self.length / 2, self.width / 2
        local = np.array([(-hl, -hw), (hl, -hw), (hl, hw), (-hl, hw)])
        return local @ np.array([[c, s], [-s, c]]) + (x, y)

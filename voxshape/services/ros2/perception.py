"""A real robot's senses as the simulator's: its scan resampled to the simulator's laser
beams and rear sonars (and, for bumps and the way back, its nearest reading all round), its
odometry as a pose. Pure.

A scan's readings follow REP 117: +inf is nothing within range_max (it reads as the laser's
far limit), -inf something nearer than range_min (the near limit); NaN, and finite readings
outside [range_min, range_max] (many drivers send 0.0 for no return), carry no information
and are left out. Each of the simulator's beams takes the nearest valid reading among the
real beams in its angular slot (the nearest real beam where the slot holds none, as with a
scan coarser than the simulator's); a slot with nothing valid reads the far limit. The scan is
taken as seen from the robot's centre, in the robot's heading (its frame's offset is left
out: a few centimetres beside what the learner reads, the nearest metre in thirds).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from voxshape.world.robot import RobotModel


@dataclass(frozen=True)
class ScanGeometry:
    """Where a scan's beams point: beam k at angle_min + k * angle_increment."""

    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float


def wrap(angles: np.ndarray) -> np.ndarray:
    """Angles in [-pi, pi)."""
    return (np.asarray(angles) + math.pi) % math.tau - math.pi


def yaw_of(qx: float, qy: float, qz: float, qw: float) -> float:
    """The heading (rotation about z) of a quaternion."""
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def cleaned(ranges: np.ndarray, geometry: ScanGeometry, far: float, near: float) -> np.ndarray:
    """The readings as metres, NaN where a reading says nothing (see the module's doc)."""
    r = np.asarray(ranges, dtype=np.float64)
    out = np.where((r >= geometry.range_min) & (r <= geometry.range_max), r, np.nan)
    out = np.where(np.isposinf(r) | (np.isfinite(r) & (r > geometry.range_max)), far, out)
    return np.where(np.isneginf(r), near, out)


def _slot_minima(
    values: np.ndarray, angles: np.ndarray, start: float, width: float, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """The nearest valid value in each of n slots of `width` from angle `start` (NaN where
    none is), and which slots hold no beam at all."""
    slot = np.floor(np.mod(angles - start, math.tau) / width).astype(int)
    inside = slot < n
    minima = np.full(n, np.inf)
    valid = inside & ~np.isnan(values)
    np.minimum.at(minima, slot[valid], values[valid])
    empty = np.ones(n, bool)
    empty[slot[inside]] = False
    return np.where(np.isinf(minima), np.nan, minima), empty


def laser_from_scan(ranges: np.ndarray, geometry: ScanGeometry, model: RobotModel) -> np.ndarray:
    """The simulator's laser (model.laser_beams over its field of view, metres)."""
    values = cleaned(ranges, geometry, model.laser_max, model.laser_min)
    angles = geometry.angle_min + geometry.angle_increment * np.arange(len(values))
    centres = model.laser_angles()
    width = model.laser_fov / model.laser_beams
    minima, empty = _slot_minima(values, angles, centres[0] - width / 2, width, len(centres))
    if empty.any() and len(values):
        # Slots between coarse beams: the nearest real beam, if it is within a slot or beam.
        gap = wrap(centres[empty][:, None] - angles[None, :])
        nearest = np.abs(gap).argmin(axis=1)
        close = np.abs(gap[np.arange(len(nearest)), nearest]) <= max(
            width, abs(geometry.angle_increment)
        )
        minima[np.flatnonzero(empty)[close]] = values[nearest[close]]
    return np.clip(
        np.where(np.isnan(minima), model.laser_max, minima), model.laser_min, model.laser_max
    )


def sonar_from_scan(ranges: np.ndarray, geometry: ScanGeometry, model: RobotModel) -> np.ndarray:
    """The simulator's rear sonars from the scan's beams within each one's cone, less the
    distance from the centre to the body's edge (a sonar sits on the body); the far limit
    where the scan does not look (a lidar that sees only ahead)."""
    values = cleaned(ranges, geometry, np.inf, 0.0)
    angles = geometry.angle_min + geometry.angle_increment * np.arange(len(values))
    out = np.full(len(model.sonar_angles), model.sonar_max)
    body = model.surface_distance(np.array(model.sonar_angles))
    for j, centre in enumerate(model.sonar_angles):
        seen = values[(np.abs(wrap(angles - centre)) <= model.sonar_cone / 2) & ~np.isnan(values)]
        if len(seen):
            out[j] = seen.min() - body[j]
    return np.clip(out, model.sonar_min, model.sonar_max)


AROUND = 360  # the all-round view's directions: one a degree, the first straight behind


def around_angles() -> np.ndarray:
    """The all-round view's directions in the robot's frame, from -pi (behind) on."""
    return -math.pi + (np.arange(AROUND) + 0.5) * math.tau / AROUND


def around_from_scan(ranges: np.ndarray, geometry: ScanGeometry) -> np.ndarray:
    """The nearest reading in each of AROUND directions all round (metres from the robot's
    centre): +inf where the scan saw nothing within its range, NaN where it does not look
    (or said nothing valid). Bumps and the way back read it (contact.py, homing.py)."""
    values = cleaned(ranges, geometry, math.inf, 0.0)
    angles = geometry.angle_min + geometry.angle_increment * np.arange(len(values))
    slot = np.floor(np.mod(angles + math.pi, math.tau) / (math.tau / AROUND)).astype(int)
    valid = ~np.isnan(values) & (slot < AROUND)
    out = np.full(AROUND, math.inf)
    np.minimum.at(out, slot[valid], values[valid])
    seen = np.zeros(AROUND, bool)
    seen[slot[valid]] = True
    return np.where(seen, out, np.nan)


@dataclass(frozen=True)
class Anchor:
    """Where odometry's frame lies in the task's: a pose read in odometry is rotated by
    `theta` and moved by (x, y). The identity until a teacher places the robot at its start
    (odometry does not see a robot carried)."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0

    def apply(self, x: float, y: float, theta: float) -> tuple[float, float, float]:
        c, s = math.cos(self.theta), math.sin(self.theta)
        return (
            self.x + c * x - s * y,
            self.y + s * x + c * y,
            math.remainder(theta + self.theta, math.tau),
        )

    @classmethod
    def placing(cls, odom: tuple[float, float, float], start: tuple[float, float, float]) -> Anchor:
        """The anchor under which odometry's `odom` pose reads as `start`."""
        theta = math.remainder(start[2] - odom[2], math.tau)
        c, s = math.cos(theta), math.sin(theta)
        return cls(
            start[0] - (c * odom[0] - s * odom[1]), start[1] - (s * odom[0] + c * odom[1]), theta
        )

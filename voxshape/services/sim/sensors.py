"""Laser and sonar ranges by ray casting in the plane.

Every map is a vertical extrusion (walls, boxes and cylinders taller than the sensors), so a
2D cast against their outlines and the other robots' footprints gives the same ranges as a 3D
ray test; tests check it against PyBullet's rayTestBatch on the same world.

The scan is compiled (numba, `voxshape/services/sim/planar.py`) with the same arithmetic as the
numpy reference (`Sensors(compiled=False)`), so the same ranges to the bit (a test compares them),
8x faster; numba is imported only where a compiled scan is made. A scan with a `reach` measures only
what lies within it (farther ranges read as the sensor's maximum) and casts only against the
segments and circles within reach: the ranges within reach are the full scan's, and a learner that
reads only near ranges pays for a handful of segments.
"""

from __future__ import annotations

import math

import numpy as np

from voxshape.world.maps import Map, Pose
from voxshape.world.robot import RobotModel


def _footprint_segments(corners: np.ndarray) -> np.ndarray:
    """The four edges (4, 4: x1 y1 x2 y2) of a footprint given by its corners."""
    return np.hstack([corners, np.roll(corners, -1, axis=0)])


def cast_numpy(
    ox: np.ndarray,
    oy: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    segments: np.ndarray,
    circles: np.ndarray,
    max_range: float,
) -> np.ndarray:
    """Distance along each ray (origin o, unit direction d) to the first segment or circle,
    or `max_range` if nothing is nearer: the reference implementation, in numpy."""
    best = np.full(ox.shape, max_range)
    if len(segments):
        px, py, qx, qy = segments.T
        ex, ey = qx - px, qy - py
        denom = dx[:, None] * ey - dy[:, None] * ex
        wx, wy = px - ox[:, None], py - oy[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (wx * ey - wy * ex) / denom
            u = (wx * dy[:, None] - wy * dx[:, None]) / denom
        hit = (t >= 0) & (u >= 0) & (u <= 1)
        best = np.minimum(best, np.where(hit, t, max_range).min(axis=1))
    if len(circles):
        cx, cy, r = circles.T
        fx, fy = ox[:, None] - cx, oy[:, None] - cy
        b = fx * dx[:, None] + fy * dy[:, None]
        disc = b * b - (fx * fx + fy * fy - r * r)
        with np.errstate(invalid="ignore"):
            t = -b - np.sqrt(disc)
        best = np.minimum(best, np.where((disc >= 0) & (t >= 0), t, max_range).min(axis=1))
    return best


class Sensors:
    """The laser and sonar ring of every robot in a map."""

    def __init__(self, m: Map, model: RobotModel, compiled: bool = True) -> None:
        self.model = model
        self.compiled = compiled  # False: the numpy reference, full scans only
        if compiled:
            from voxshape.services.sim.planar import scan_robot  # numba: not for every process

            self._scan_robot = scan_robot
        self.segments, self.circles = m.outlines()
        self.laser_angles = model.laser_angles()
        sonar = model.sonar_ray_angles()
        self.sonar_angles = sonar.ravel()
        self.sonar_start = model.surface_distance(self.sonar_angles)  # sonars sit on the body

    def scan(self, poses: list[Pose], reach: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Laser (robots, beams) and sonar (robots, sonars) ranges in metres, noise-free. Each
        robot sees the walls, the obstacles and the other robots; with `reach`, nothing
        farther than `reach` metres (those ranges read as the maximum)."""
        if reach is not None and not self.compiled:
            raise ValueError("a scan with a reach needs the compiled ray cast")
        m = self.model
        several = len(poses) > 1
        bodies = [_footprint_segments(m.corners(p.x, p.y, p.theta)) for p in poses if several]
        lasers = np.empty((len(poses), len(self.laser_angles)))
        sonars = np.empty((len(poses), len(m.sonar_angles)))
        for i, pose in enumerate(poses):
            others = [b for j, b in enumerate(bodies) if j != i]
            segments = np.vstack([self.segments, *others]) if others else self.segments
            if self.compiled:
                self._scan_robot(
                    pose.x,
                    pose.y,
                    pose.theta,
                    self.laser_angles,
                    m.laser_x,
                    self.sonar_angles,
                    self.sonar_start,
                    m.sonar_rays,
                    segments,
                    self.circles,
                    m.circumradius,
                    np.inf if reach is None else reach,
                    lasers[i],
                    sonars[i],
                    (m.laser_min, m.laser_max),
                    (m.sonar_min, m.sonar_max),
                    m.laser_fov <= math.pi,
                )
            else:
                laser, sonar = self._scan_numpy(pose, segments)
                lasers[i] = np.clip(laser, m.laser_min, m.laser_max)
                sonars[i] = np.clip(sonar, m.sonar_min, m.sonar_max)
        return lasers, sonars

    def _scan_numpy(self, pose: Pose, segments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m = self.model
        c, s = math.cos(pose.theta), math.sin(pose.theta)
        a = pose.theta + self.laser_angles
        lx, ly = pose.x + m.laser_x * c, pose.y + m.laser_x * s
        n = len(a)
        laser = cast_numpy(
            np.full(n, lx), np.full(n, ly), np.cos(a), np.sin(a), segments, self.circles, np.inf
        )
        b = pose.theta + self.sonar_angles
        cb, sb = np.cos(b), np.sin(b)
        ox, oy = pose.x + self.sonar_start * cb, pose.y + self.sonar_start * sb
        sonar = cast_numpy(ox, oy, cb, sb, segments, self.circles, np.inf)
        return laser, sonar.reshape(len(m.sonar_angles), -1).min(axis=1)

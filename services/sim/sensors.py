"""Laser and sonar ranges by ray casting in the plane.

Every map is a vertical extrusion (walls, boxes and cylinders taller than the sensors), so a
2D cast against their outlines and the other robots' footprints gives the same ranges as a 3D
ray test; tests check it against PyBullet's rayTestBatch on the same world.

The scan is compiled (numba, `scan_robot`) with the same arithmetic as the numpy reference
(`Sensors(compiled=False)`), so the same ranges to the bit (a test compares them). A scan
with a `reach` measures only what lies within it (farther ranges read as the sensor's
maximum) and casts only against the segments and circles within reach of the robot's body:
the ranges within reach are the full scan's, and a learner that reads only near ranges pays
for a handful of segments.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from services.sim.maps import Box, Map, Pose
from services.sim.robot import RobotModel

REACH_SLACK = 0.01  # metres added to the culling distance of a reach, against rounding


def _outline_segments(shapes: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Box outlines as segments (m, 4: x1 y1 x2 y2) and cylinders as circles (k, 3: x y r)."""
    segments, circles = [], []
    for shape in shapes:
        if isinstance(shape, Box):
            pts = shape.corners()
            segments += [(*pts[i], *pts[(i + 1) % 4]) for i in range(4)]
        else:
            circles.append((shape.x, shape.y, shape.radius))
    return np.array(segments, float).reshape(-1, 4), np.array(circles, float).reshape(-1, 3)


def _footprint_segments(corners: np.ndarray) -> np.ndarray:
    """The four edges (4, 4: x1 y1 x2 y2) of a footprint given by its corners."""
    return np.hstack([corners, np.roll(corners, -1, axis=0)])


@njit(cache=True)
def _within(segments: np.ndarray, circles: np.ndarray, x: float, y: float, d: float) -> tuple:
    """The indices of the segments and of the circles within d metres of (x, y)."""
    near_segments, near_circles = [], []
    for k in range(segments.shape[0]):
        px, py = segments[k, 0], segments[k, 1]
        ex, ey = segments[k, 2] - px, segments[k, 3] - py
        length2 = ex * ex + ey * ey
        s = 0.0 if length2 == 0.0 else ((x - px) * ex + (y - py) * ey) / length2
        s = min(1.0, max(0.0, s))
        if math.hypot(px + s * ex - x, py + s * ey - y) <= d:
            near_segments.append(k)
    for k in range(circles.shape[0]):
        if math.hypot(circles[k, 0] - x, circles[k, 1] - y) - circles[k, 2] <= d:
            near_circles.append(k)
    return near_segments, near_circles


@njit(cache=True, error_model="numpy")
def _cast(
    ox: float,
    oy: float,
    dx: float,
    dy: float,
    segments: np.ndarray,
    circles: np.ndarray,
    near_segments: list,
    near_circles: list,
) -> float:
    """Distance along a ray (origin o, unit direction d) to the first of the given segments
    and circles, inf if none; as `cast_numpy`, operation for operation."""
    nearest = np.inf
    for k in near_segments:
        px, py = segments[k, 0], segments[k, 1]
        ex, ey = segments[k, 2] - px, segments[k, 3] - py
        denom = dx * ey - dy * ex
        wx, wy = px - ox, py - oy
        u = (wx * dy - wy * dx) / denom
        if u >= 0 and u <= 1:
            t = (wx * ey - wy * ex) / denom
            if t >= 0 and t < nearest:
                nearest = t
    for k in near_circles:
        fx, fy = ox - circles[k, 0], oy - circles[k, 1]
        r = circles[k, 2]
        b = fx * dx + fy * dy
        disc = b * b - (fx * fx + fy * fy - r * r)
        if disc >= 0:
            t = -b - math.sqrt(disc)
            if t >= 0 and t < nearest:
                nearest = t
    return nearest


@njit(cache=True, error_model="numpy")
def scan_robot(
    x: float,
    y: float,
    theta: float,
    laser_angles: np.ndarray,
    laser_x: float,
    sonar_angles: np.ndarray,
    sonar_start: np.ndarray,
    sonar_rays: int,
    segments: np.ndarray,
    circles: np.ndarray,
    body_radius: float,
    reach: float,
) -> tuple[np.ndarray, np.ndarray]:
    """One robot's raw laser (beams) and sonar (sonars, the nearest of each one's rays)
    ranges at (x, y, theta), inf where nothing is nearer than `reach` (np.inf: anywhere)."""
    near_segments, near_circles = _within(
        segments, circles, x, y, reach + body_radius + REACH_SLACK
    )
    lx, ly = x + laser_x * math.cos(theta), y + laser_x * math.sin(theta)
    laser = np.empty(laser_angles.shape[0])
    for i in range(laser_angles.shape[0]):
        a = theta + laser_angles[i]
        r = _cast(lx, ly, math.cos(a), math.sin(a), segments, circles, near_segments, near_circles)
        laser[i] = r if r < reach else np.inf
    sonar = np.full(sonar_angles.shape[0] // sonar_rays, np.inf)
    for j in range(sonar_angles.shape[0]):
        b = theta + sonar_angles[j]
        cb, sb = math.cos(b), math.sin(b)
        ox, oy = x + sonar_start[j] * cb, y + sonar_start[j] * sb
        r = _cast(ox, oy, cb, sb, segments, circles, near_segments, near_circles)
        if r < reach:
            sonar[j // sonar_rays] = min(sonar[j // sonar_rays], r)
    return laser, sonar


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
        self.segments, self.circles = _outline_segments(m.shapes)
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
        lasers, sonars = [], []
        for i, pose in enumerate(poses):
            others = [b for j, b in enumerate(bodies) if j != i]
            segments = np.vstack([self.segments, *others]) if others else self.segments
            if self.compiled:
                laser, sonar = scan_robot(
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
                )
            else:
                laser, sonar = self._scan_numpy(pose, segments)
            lasers.append(np.clip(laser, m.laser_min, m.laser_max))
            sonars.append(np.clip(sonar, m.sonar_min, m.sonar_max))
        return np.array(lasers), np.array(sonars)

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

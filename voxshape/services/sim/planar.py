"""Compiled planar geometry (numba, cached on disk after the first compilation): the ray
cast of `voxshape/services/sim/sensors.py`, with the arithmetic of its numpy reference
(`sensors.cast_numpy`) in the same order, so the same ranges to the bit; and the clearance
of a robot's footprint, which tells `voxshape/services/sim/world.py` when PyBullet need not be asked
about contacts."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

REACH_SLACK = 0.01  # metres added to the culling distance of a reach, against rounding


@njit(cache=True)
def _within(
    segments: np.ndarray,
    circles: np.ndarray,
    x: float,
    y: float,
    d: float,
    hx: float = 0.0,
    hy: float = 0.0,
) -> tuple:
    """The indices of the segments and of the circles within d metres of (x, y) and, for a
    direction h other than (0, 0), not wholly behind (x, y) as seen along h."""
    near_segments, near_circles = [], []
    for k in range(segments.shape[0]):
        px, py = segments[k, 0], segments[k, 1]
        ex, ey = segments[k, 2] - px, segments[k, 3] - py
        if (px - x) * hx + (py - y) * hy < 0 and (px + ex - x) * hx + (py + ey - y) * hy < 0:
            continue
        length2 = ex * ex + ey * ey
        s = 0.0 if length2 == 0.0 else ((x - px) * ex + (y - py) * ey) / length2
        s = min(1.0, max(0.0, s))
        if math.hypot(px + s * ex - x, py + s * ey - y) <= d:
            near_segments.append(k)
    for k in range(circles.shape[0]):
        cx, cy, r = circles[k, 0], circles[k, 1], circles[k, 2]
        if (cx - x) * hx + (cy - y) * hy < -r:
            continue
        if math.hypot(cx - x, cy - y) - r <= d:
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
    laser: np.ndarray,
    sonar: np.ndarray,
    laser_range: tuple[float, float],
    sonar_range: tuple[float, float],
    frontal: bool,
) -> None:
    """One robot's laser (beams) and sonar (sonars, the nearest of each one's rays) ranges
    at (x, y, theta) into `laser` and `sonar`, clipped to each sensor's (min, max) range;
    the maximum where nothing is nearer than `reach` (np.inf: anywhere). Each ray is cast
    only against what lies within reach of its origin: for the laser, of its one origin and
    ahead of it (`frontal`: its beams all point ahead); for the sonars, of the body."""
    lx, ly = x + laser_x * math.cos(theta), y + laser_x * math.sin(theta)
    hx, hy = (math.cos(theta), math.sin(theta)) if frontal else (0.0, 0.0)
    ahead_segments, ahead_circles = _within(segments, circles, lx, ly, reach + REACH_SLACK, hx, hy)
    for i in range(laser_angles.shape[0]):
        a = theta + laser_angles[i]
        r = _cast(
            lx, ly, math.cos(a), math.sin(a), segments, circles, ahead_segments, ahead_circles
        )
        laser[i] = _clip(r if r < reach else np.inf, laser_range)
    near_segments, near_circles = _within(
        segments, circles, x, y, reach + body_radius + REACH_SLACK
    )
    sonar[:] = np.inf
    for j in range(sonar_angles.shape[0]):
        b = theta + sonar_angles[j]
        cb, sb = math.cos(b), math.sin(b)
        ox, oy = x + sonar_start[j] * cb, y + sonar_start[j] * sb
        r = _cast(ox, oy, cb, sb, segments, circles, near_segments, near_circles)
        if r < reach:
            sonar[j // sonar_rays] = min(sonar[j // sonar_rays], r)
    for k in range(sonar.shape[0]):
        sonar[k] = _clip(sonar[k], sonar_range)


@njit(cache=True)
def _clip(r: float, limits: tuple[float, float]) -> float:
    """r within limits (as np.clip)."""
    return min(max(r, limits[0]), limits[1])


@njit(cache=True)
def _point_segment(px: float, py: float, ax: float, ay: float, bx: float, by: float) -> float:
    """The distance from point p to segment ab."""
    ex, ey = bx - ax, by - ay
    length2 = ex * ex + ey * ey
    s = 0.0 if length2 == 0.0 else ((px - ax) * ex + (py - ay) * ey) / length2
    s = min(1.0, max(0.0, s))
    return math.hypot(ax + s * ex - px, ay + s * ey - py)


@njit(cache=True)
def _cross(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> float:
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@njit(cache=True)
def footprint_clearance(
    x: float,
    y: float,
    theta: float,
    half_length: float,
    half_width: float,
    segments: np.ndarray,
    circles: np.ndarray,
) -> float:
    """The distance from a robot's rectangle at (x, y, theta) to the nearest segment or
    circle, 0 where they cross or the rectangle holds a circle's centre."""
    c, s = math.cos(theta), math.sin(theta)
    corners = np.empty((4, 2))
    for k, (lx, ly) in enumerate(
        ((-half_length, -half_width), (half_length, -half_width),
         (half_length, half_width), (-half_length, half_width))
    ):  # fmt: skip
        corners[k, 0], corners[k, 1] = x + c * lx - s * ly, y + s * lx + c * ly
    best = np.inf
    for k in range(segments.shape[0]):
        px, py, qx, qy = segments[k, 0], segments[k, 1], segments[k, 2], segments[k, 3]
        for e in range(4):
            ax, ay = corners[e, 0], corners[e, 1]
            bx, by = corners[(e + 1) % 4, 0], corners[(e + 1) % 4, 1]
            d1, d2 = _cross(ax, ay, bx, by, px, py), _cross(ax, ay, bx, by, qx, qy)
            d3, d4 = _cross(px, py, qx, qy, ax, ay), _cross(px, py, qx, qy, bx, by)
            if d1 * d2 <= 0 and d3 * d4 <= 0:
                return 0.0  # they cross (or touch)
            best = min(
                best,
                _point_segment(px, py, ax, ay, bx, by),
                _point_segment(qx, qy, ax, ay, bx, by),
                _point_segment(ax, ay, px, py, qx, qy),
                _point_segment(bx, by, px, py, qx, qy),
            )
    for k in range(circles.shape[0]):
        cx, cy, r = circles[k, 0], circles[k, 1], circles[k, 2]
        lx, ly = c * (cx - x) + s * (cy - y), -s * (cx - x) + c * (cy - y)  # in the robot frame
        dx, dy = max(abs(lx) - half_length, 0.0), max(abs(ly) - half_width, 0.0)
        best = min(best, max(math.hypot(dx, dy) - r, 0.0))
    return best

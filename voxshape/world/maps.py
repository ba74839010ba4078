"""Task maps: a small TOML format, its validating loader, and the map's free-space grid.

A map file's format is in docs/simulator.md#your-own-map (examples: `voxshape/world/maps/`).

The loader checks every key and value, that the start (with its jitter) leaves the robot
clear of walls and obstacles, and that the goal can be reached by a robot of the given size.
This module is pure (numpy; `--task` is a setting of voxshape/runtime): the simulator, the
renderer and the simulated teacher all build on the same `Map`.
"""

from __future__ import annotations

import argparse
import functools
import heapq
import math
import os
import tomllib
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from voxshape.runtime.settings import option, option_of
from voxshape.world.task import Goal

MAPS_DIR = Path(__file__).with_name("maps")
TASKS = {str(i): MAPS_DIR / f"task{i}.toml" for i in range(1, 5)}
GRID_RESOLUTION = 0.05  # metres per cell of the free-space grid
DEFAULT_WALL_HEIGHT = 0.5


class MapError(ValueError):
    """A map that cannot be used; the message names the file, the entry and the fix."""


@dataclass(frozen=True)
class Box:
    """An oriented box obstacle (walls are boxes too)."""

    x: float
    y: float
    width: float
    depth: float
    angle: float = 0.0  # radians

    def corners(self) -> list[tuple[float, float]]:
        """The four corners, counter-clockwise."""
        c, s = math.cos(self.angle), math.sin(self.angle)
        hw, hd = self.width / 2, self.depth / 2
        return [
            (self.x + c * dx - s * dy, self.y + s * dx + c * dy)
            for dx, dy in ((-hw, -hd), (hw, -hd), (hw, hd), (-hw, hd))
        ]

    def distance(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """Signed distance from points to the box surface (negative inside)."""
        c, s = math.cos(self.angle), math.sin(self.angle)
        dx, dy = px - self.x, py - self.y
        lx, ly = np.abs(c * dx + s * dy) - self.width / 2, np.abs(-s * dx + c * dy) - self.depth / 2
        outside = np.hypot(np.maximum(lx, 0), np.maximum(ly, 0))
        return outside + np.minimum(np.maximum(lx, ly), 0)


@dataclass(frozen=True)
class Cylinder:
    x: float
    y: float
    radius: float

    def distance(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        return np.hypot(px - self.x, py - self.y) - self.radius


Shape = Box | Cylinder


@dataclass(frozen=True)
class Pose:
    x: float
    y: float
    theta: float  # radians


@dataclass(frozen=True)
class Map:
    name: str
    source: str
    width: float
    height: float
    timeout: float
    shapes: tuple[Shape, ...]  # border, walls and obstacles
    start: Pose
    start_jitter: Pose  # half-widths of the uniform noise
    goal_x: float
    goal_y: float
    goal_radius: float
    wall_height: float = DEFAULT_WALL_HEIGHT

    def clearance(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """Distance from points to the nearest wall or obstacle surface (negative inside)."""
        px, py = np.asarray(px, float), np.asarray(py, float)
        return np.min([shape.distance(px, py) for shape in self.shapes], axis=0)

    def outlines(self) -> tuple[np.ndarray, np.ndarray]:
        """Box outlines as segments (m, 4: x1 y1 x2 y2) and cylinders as circles (k, 3: x y r)."""
        segments, circles = [], []
        for shape in self.shapes:
            if isinstance(shape, Box):
                pts = shape.corners()
                segments += [(*pts[i], *pts[(i + 1) % 4]) for i in range(4)]
            else:
                circles.append((shape.x, shape.y, shape.radius))
        return np.array(segments, float).reshape(-1, 4), np.array(circles, float).reshape(-1, 3)

    @property
    def goal(self) -> Goal:
        return Goal(self.goal_x, self.goal_y, self.goal_radius)

    @cached_property
    def grid(self) -> FreeSpace:
        return FreeSpace(self)

    def shortest_time(self, speed: float) -> float:
        """Seconds the shortest way from the start to the goal takes at `speed` (m/s): a
        lower bound on any episode that reaches the goal."""
        distance = self.grid.distances_to_goal(PASSAGE_RADIUS)
        return float(distance[self.grid.cell(self.start.x, self.start.y)]) / speed


class FreeSpace:
    """The map on a grid: clearance per cell and geodesic distances around obstacles."""

    def __init__(self, m: Map, resolution: float = GRID_RESOLUTION) -> None:
        self.map = m
        self.resolution = resolution
        self.cols = max(1, round(m.width / resolution))
        self.rows = max(1, round(m.height / resolution))
        xs = (np.arange(self.cols) + 0.5) * resolution
        ys = (np.arange(self.rows) + 0.5) * resolution
        px, py = np.meshgrid(xs, ys)  # [row, col]
        self.clearance = m.clearance(px, py)
        self.clearance.flags.writeable = False
        self._clearance_rows = self.clearance.tolist()  # for one cell at a time, no numpy
        self._half_diagonal = resolution / math.sqrt(2)
        self._distances: dict[float, np.ndarray] = {}

    def cell(self, x: float, y: float) -> tuple[int, int]:
        col = min(self.cols - 1, max(0, int(x / self.resolution)))
        row = min(self.rows - 1, max(0, int(y / self.resolution)))
        return row, col

    def clearance_bound(self, x: float, y: float) -> float:
        """A lower bound on the clearance at (x, y): its cell's, less the farthest a point of
        the cell lies from the cell's centre (a distance changes no faster than the point
        moves); -inf off the grid."""
        col, row = int(x / self.resolution), int(y / self.resolution)
        if not (0 <= col < self.cols and 0 <= row < self.rows and x >= 0 and y >= 0):
            return -math.inf
        return self._clearance_rows[row][col] - self._half_diagonal

    def distances_to_goal(self, robot_radius: float) -> np.ndarray:
        """Geodesic distance (metres) from every cell to the goal region for a robot whose
        centre must keep `robot_radius` from obstacles; inf where the goal cannot be reached.
        Computed once per radius (read-only)."""
        if robot_radius not in self._distances:
            self._distances[robot_radius] = self._dijkstra(robot_radius)
            self._distances[robot_radius].flags.writeable = False
        return self._distances[robot_radius]

    def _dijkstra(self, robot_radius: float) -> np.ndarray:
        m = self.map
        free = self.clearance >= robot_radius
        dist = np.full(free.shape, np.inf)
        heap: list[tuple[float, int, int]] = []
        ys = (np.arange(self.rows) + 0.5) * self.resolution
        xs = (np.arange(self.cols) + 0.5) * self.resolution
        in_goal = m.goal.contains(xs[None, :], ys[:, None])
        for row, col in zip(*np.nonzero(in_goal & free), strict=True):
            dist[row, col] = 0.0
            heap.append((0.0, int(row), int(col)))
        heapq.heapify(heap)
        steps = [
            (dr, dc, math.hypot(dr, dc) * self.resolution)
            for dr in (-1, 0, 1)
            for dc in (-1, 0, 1)
            if dr or dc
        ]
        while heap:
            d, row, col = heapq.heappop(heap)
            if d > dist[row, col]:
                continue
            for dr, dc, cost in steps:
                r, c = row + dr, col + dc
                if (
                    0 <= r < self.rows
                    and 0 <= c < self.cols
                    and free[r, c]
                    and d + cost < dist[r, c]
                ):
                    dist[r, c] = d + cost
                    heapq.heappush(heap, (d + cost, r, c))
        return dist


# -- loading --------------------------------------------------------------------------------

ROBOT_CLEARANCE = 0.30  # circumradius of the Pioneer-2-like footprint (0.45 x 0.38 m)
PASSAGE_RADIUS = 0.22  # half the narrowest width the robot fits through, with a margin


def load_map(name_or_path: str | Path) -> Map:
    """A task number ("1".."4") or a map file path; raises MapError naming what is wrong."""
    path = TASKS.get(str(name_or_path), Path(name_or_path))
    if not path.is_file():
        raise MapError(
            f"unknown map {str(name_or_path)!r}: give a task number ({', '.join(TASKS)}) "
            "or the path of a map file (format: docs/simulator.md#your-own-map)"
        )
    return _parsed(path.resolve(), path.stat().st_mtime_ns, str(path))


@functools.lru_cache(maxsize=32)
def _parsed(path: Path, mtime_ns: int, shown: str) -> Map:
    """A map file read once per version: its grid and geodesic distances, computed on first
    use, serve every later run in the process (a Map and its grid are read-only)."""
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise MapError(f"{shown}: not valid TOML: {e}") from None
    return parse_map(data, shown)


def _number(value: object, where: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise MapError(f"{where}: expected a number, got {value!r}")
    if not lo <= value <= hi:
        raise MapError(f"{where}: {value} is outside [{lo:g}, {hi:g}]")
    return float(value)


def _numbers(value: object, n: int, where: str, lo: float = -math.inf) -> list[float]:
    if not isinstance(value, list) or len(value) != n:
        raise MapError(f"{where}: expected a list of {n} numbers, got {value!r}")
    return [_number(v, f"{where}[{i}]", lo) for i, v in enumerate(value)]


def _table(data: dict, key: str, allowed: set[str], source: str) -> dict:
    value = data.get(key)
    if not isinstance(value, dict):
        raise MapError(f"{source}: needs a [{key}] table")
    unknown = sorted(set(value) - allowed)
    if unknown:
        raise MapError(f"{source} [{key}]: unknown key {unknown[0]!r}; allowed: {sorted(allowed)}")
    return value


_MAP_KEYS = {
    "name",
    "size",
    "timeout",
    "wall_thickness",
    "walls",
    "boxes",
    "cylinders",
    "start",
    "goal",
    "description",
}


def parse_map(data: dict, source: str = "<map>") -> Map:
    unknown = sorted(set(data) - _MAP_KEYS)
    if unknown:
        raise MapError(f"{source}: unknown key {unknown[0]!r}; allowed: {sorted(_MAP_KEYS)}")
    name = data.get("name")
    if not isinstance(name, str) or not name:
        raise MapError(f'{source}: needs `name = "..."`')
    width, height = _numbers(data.get("size"), 2, f"{source} size", lo=1.0)
    timeout = _number(data.get("timeout"), f"{source} timeout", 1.0, 1e5)
    thickness = _number(data.get("wall_thickness", 0.1), f"{source} wall_thickness", 0.01, 2.0)
    shapes = [
        *_border(width, height, thickness),
        *_walls(data, thickness, source),
        *_boxes(data, source),
        *_cylinders(data, source),
    ]
    start, jitter = _start(data, source)
    gx, gy, radius = _goal(data, source)
    m = Map(
        name=name,
        source=source,
        width=width,
        height=height,
        timeout=timeout,
        shapes=tuple(shapes),
        start=start,
        start_jitter=jitter,
        goal_x=gx,
        goal_y=gy,
        goal_radius=radius,
    )
    _check_layout(m)
    return m


def _border(width: float, height: float, thickness: float) -> list[Shape]:
    """The four walls around the [0, width] x [0, height] floor, just outside it."""
    return [
        Box(width / 2, -thickness / 2, width + 2 * thickness, thickness),
        Box(width / 2, height + thickness / 2, width + 2 * thickness, thickness),
        Box(-thickness / 2, height / 2, thickness, height),
        Box(width + thickness / 2, height / 2, thickness, height),
    ]


def _walls(data: dict, thickness: float, source: str) -> list[Shape]:
    """`walls = [[x1, y1, x2, y2], ...]`: boxes `thickness` wide, overlapping at the ends."""
    shapes: list[Shape] = []
    for i, wall in enumerate(data.get("walls", [])):
        x1, y1, x2, y2 = _numbers(wall, 4, f"{source} walls[{i}]")
        length = math.hypot(x2 - x1, y2 - y1)
        if length == 0:
            raise MapError(f"{source} walls[{i}]: the two ends are the same point")
        angle = math.atan2(y2 - y1, x2 - x1)
        shapes.append(Box((x1 + x2) / 2, (y1 + y2) / 2, length + thickness, thickness, angle))
    return shapes


def _boxes(data: dict, source: str) -> list[Shape]:
    """`[[boxes]]`: center, size and angle in degrees."""
    shapes: list[Shape] = []
    for i, box in enumerate(data.get("boxes", [])):
        where = f"{source} boxes[{i}]"
        if not isinstance(box, dict) or set(box) - {"center", "size", "angle"}:
            raise MapError(f"{where}: expected center = [x, y], size = [w, d], angle = degrees")
        x, y = _numbers(box.get("center"), 2, f"{where} center")
        w, d = _numbers(box.get("size"), 2, f"{where} size", lo=0.01)
        angle = math.radians(_number(box.get("angle", 0.0), f"{where} angle"))
        shapes.append(Box(x, y, w, d, angle))
    return shapes


def _cylinders(data: dict, source: str) -> list[Shape]:
    """`[[cylinders]]`: center and radius."""
    shapes: list[Shape] = []
    for i, cyl in enumerate(data.get("cylinders", [])):
        where = f"{source} cylinders[{i}]"
        if not isinstance(cyl, dict) or set(cyl) - {"center", "radius"}:
            raise MapError(f"{where}: expected center = [x, y], radius = r")
        x, y = _numbers(cyl.get("center"), 2, f"{where} center")
        shapes.append(Cylinder(x, y, _number(cyl.get("radius"), f"{where} radius", 0.01)))
    return shapes


def _start(data: dict, source: str) -> tuple[Pose, Pose]:
    """The [start] table: the pose and its jitter (degrees in the file, radians here)."""
    start = _table(data, "start", {"pose", "jitter"}, source)
    sx, sy, sdeg = _numbers(start.get("pose"), 3, f"{source} [start] pose")
    jx, jy, jdeg = _numbers(start.get("jitter", [0, 0, 0]), 3, f"{source} [start] jitter", lo=0)
    return Pose(sx, sy, math.radians(sdeg)), Pose(jx, jy, math.radians(jdeg))


def _goal(data: dict, source: str) -> tuple[float, float, float]:
    """The [goal] table: its center x, y and radius."""
    goal = _table(data, "goal", {"center", "radius"}, source)
    gx, gy = _numbers(goal.get("center"), 2, f"{source} [goal] center")
    return gx, gy, _number(goal.get("radius"), f"{source} [goal] radius", 0.05)


def _check_layout(m: Map) -> None:
    s, j = m.start, m.start_jitter
    for x, y in ((s.x + dx, s.y + dy) for dx in (-j.x, 0, j.x) for dy in (-j.y, 0, j.y)):
        if not (0 < x < m.width and 0 < y < m.height):
            raise MapError(
                f"{m.source} [start]: ({x:g}, {y:g}) is outside the {m.width:g} x "
                f"{m.height:g} m floor"
            )
        room = float(m.clearance(x, y))
        if room < ROBOT_CLEARANCE:
            raise MapError(
                f"{m.source} [start]: the robot at ({x:g}, {y:g}) would overlap a wall or "
                f"obstacle: it needs {ROBOT_CLEARANCE:.2f} m of clearance, has {room:.2f} m. "
                "Move the start pose or reduce its jitter."
            )
    if not (0 < m.goal_x < m.width and 0 < m.goal_y < m.height):
        raise MapError(f"{m.source} [goal]: ({m.goal_x:g}, {m.goal_y:g}) is outside the floor")
    distances = m.grid.distances_to_goal(PASSAGE_RADIUS)
    if not np.isfinite(distances[m.grid.cell(s.x, s.y)]):
        raise MapError(
            f"{m.source} [goal]: unreachable from the start for a robot that needs passages "
            f"{2 * PASSAGE_RADIUS:.2f} m wide (is it walled in, or inside an obstacle?)"
        )


def task_option(why: str) -> Any:
    """`--task`, a field of a command's options: the session's map, as the simulator runs it
    (VOXSHAPE_TASK, default 1)."""
    return option(
        "1",
        f"the simulator's map: task number ({', '.join(TASKS)}) or map file, {why}",
        env="VOXSHAPE_TASK",
    )


def add_task_argument(parser: argparse.ArgumentParser, why: str) -> None:
    """`--task` for a command that reads `args.task` itself: task_option's flag, its value
    (the flag, else VOXSHAPE_TASK, else 1) there at once."""
    task = task_option(why)
    how = option_of(task)
    assert how is not None and how.env is not None
    default = os.environ.get(how.env) or task.default
    parser.add_argument(
        "--task", default=default, help=f"{how.help} ({how.env}; default {task.default})"
    )

"""The map's true shortest way to its goal, around walls and obstacles: the distance from any
pose, its downhill heading, the point a little way down it and the command that follows it.
What the simulated person knows of the way, the experiments' measure of which way the words
pushed, and the oracle potential (the ceiling of a potential over places)."""

from __future__ import annotations

import math

import numpy as np

from voxshape.world.maps import PASSAGE_RADIUS, Map

NEAREST_FREE_CELLS = 10  # a pose too near a wall takes the distance of a free cell this near
# Metres kept between the robot's centre and the walls when dictating a path: the widest
# berth through which the goal can be reached from the pose (task 4's door is narrower than
# twice the first).
BERTHS = (0.45, 0.35, PASSAGE_RADIUS)
RETURN_CELLS = 20  # nearer a wall than the berth: head for a cell with it at most this near
FACING = math.radians(20)  # dictating: "forward" when the path is within this of the heading


class GeodesicDistance:
    """The true distance to the goal, around obstacles, from any pose the robot can take."""

    def __init__(self, m: Map, robot_radius: float = PASSAGE_RADIUS) -> None:
        self.grid = m.grid
        self.distance = m.grid.distances_to_goal(robot_radius)

    def __call__(self, x: float, y: float) -> float:
        row, col = self.grid.cell(x, y)
        d = self.distance[row, col]
        if math.isfinite(d):
            return float(d)
        for ring in range(1, NEAREST_FREE_CELLS + 1):  # hugging a wall: the nearest free cell
            r0, r1 = max(0, row - ring), min(self.grid.rows, row + ring + 1)
            c0, c1 = max(0, col - ring), min(self.grid.cols, col + ring + 1)
            window = self.distance[r0:r1, c0:c1]
            if np.isfinite(window).any():
                return float(window[np.isfinite(window)].min() + ring * self.grid.resolution)
        return math.inf


def downhill_heading(m: Map, x: float, y: float) -> float | None:
    """The direction of steepest descent of the geodesic distance near (x, y), keeping the
    widest berth from the walls that leads from the start to the goal; a robot nearer a wall
    than that is first sent back to the nearest cell with that berth. None where there is no
    way down (in the goal, or boxed in)."""
    grid = m.grid
    row, col = grid.cell(x, y)
    start = grid.cell(m.start.x, m.start.y)
    berth = next((b for b in BERTHS if math.isfinite(grid.distances_to_goal(b)[start])), BERTHS[-1])
    distance = grid.distances_to_goal(berth)
    if not math.isfinite(distance[row, col]):
        for ring in range(1, RETURN_CELLS + 1):
            r0, c0 = max(0, row - ring), max(0, col - ring)
            window = distance[r0 : row + ring + 1, c0 : col + ring + 1]
            offsets = np.argwhere(np.isfinite(window)) + np.array([r0 - row, c0 - col])
            if len(offsets):
                dr, dc = offsets[np.argmin(np.hypot(offsets[:, 0], offsets[:, 1]))]
                return math.atan2(dr, dc)
        distance = grid.distances_to_goal(BERTHS[-1])
    best, best_distance = None, distance[row, col]
    for dr in (-2, -1, 0, 1, 2):
        for dc in (-2, -1, 0, 1, 2):
            r, c = row + dr, col + dc
            if 0 <= r < grid.rows and 0 <= c < grid.cols and distance[r, c] < best_distance:
                best, best_distance = (dr, dc), distance[r, c]
    return math.atan2(best[0], best[1]) if best else None


def way_ahead(m: Map, x: float, y: float, lookahead: float) -> tuple[float, float] | None:
    """The point `lookahead` metres down the shortest way from (x, y), with the widest berth
    from the walls that leads from the start to the goal (from the nearest cell with that
    berth when nearer a wall than it): where a person steering by eye aims. None in the goal
    or boxed in."""
    grid = m.grid
    start = grid.cell(m.start.x, m.start.y)
    berth = next((b for b in BERTHS if math.isfinite(grid.distances_to_goal(b)[start])), BERTHS[-1])
    distance = grid.distances_to_goal(berth)
    row, col = grid.cell(x, y)
    if not math.isfinite(distance[row, col]):
        r0, c0 = max(0, row - RETURN_CELLS), max(0, col - RETURN_CELLS)
        window = distance[r0 : row + RETURN_CELLS + 1, c0 : col + RETURN_CELLS + 1]
        free = np.argwhere(np.isfinite(window))
        if not len(free):
            return None
        dr, dc = free[np.argmin(np.hypot(*(free - (row - r0, col - c0)).T))] + (r0, c0)
        row, col = int(dr), int(dc)
    walked = 0.0
    while walked < lookahead:
        best = None
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                r, c = row + dr, col + dc
                if (
                    0 <= r < grid.rows
                    and 0 <= c < grid.cols
                    and distance[r, c] < distance[best or (row, col)]
                ):
                    best = (r, c)
        if best is None:
            break
        walked += math.hypot(best[0] - row, best[1] - col) * grid.resolution
        row, col = best
    ax, ay = (col + 0.5) * grid.resolution, (row + 0.5) * grid.resolution
    return None if math.hypot(ax - x, ay - y) < grid.resolution else (ax, ay)


def path_command(m: Map, x: float, y: float, theta: float, facing: float = FACING) -> str:
    """The command that follows the shortest path: forward when facing it (within `facing`
    radians), else turn to it."""
    heading = downhill_heading(m, x, y)
    error = 0.0 if heading is None else math.remainder(heading - theta, math.tau)
    if abs(error) < facing:
        return "forward"
    return "left" if error > 0 else "right"

"""The robot's guess of the way: a potential Phi over its place, in metres (higher: further
along the way), built here for every value of the `potential` setting.

- "straight_line" (the default): Phi(x, y) = -|(x, y) - goal|, the goal read from the
  observations' goal fields, so a robot nobody talks to heads for its goal as the crow flies
  where its laser shows the way free, and learns where the straight line is wrong;
- "oracle": minus the map's true shortest way (voxshape/world/geodesic.py): the ceiling of
  what a guess over places can carry. It needs the map, so a learner without one refuses it;
- "none": no guess (the paper's learner, which knows nothing of where its goal is).

The learner gets Phi as shaping, F = gamma^k Phi(s') - Phi(s) (Ng, Harada & Russell 1999: it
keeps the optimal policy), corrected where a person's words turn the way (way.py), and its
policy looks ahead along it (sarsa.py `_expected_progress`)."""

from __future__ import annotations

import math
from typing import Protocol

from voxshape.world.geodesic import GeodesicDistance
from voxshape.world.maps import Map

Place = tuple[float, float]


class Potential(Protocol):
    """Phi over places, in metres (higher: further along the way)."""

    def value(self, x: float, y: float) -> float: ...


class StraightLine:
    """Minus the straight line to the goal; 0 until the goal is known."""

    def __init__(self, goal: Place | None = None) -> None:
        self.goal = goal

    def value(self, x: float, y: float) -> float:
        if self.goal is None:
            return 0.0
        return -math.hypot(x - self.goal[0], y - self.goal[1])


class ShortestWay:
    """Minus the map's true shortest way to its goal."""

    def __init__(self, m: Map) -> None:
        self.distance = GeodesicDistance(m)

    def value(self, x: float, y: float) -> float:
        return -self.distance(x, y)


def potential_for(name: str, task: Map | None) -> Potential | None:
    """The guess the `potential` setting names; ValueError if it cannot be built here."""
    if name == "straight_line":
        return StraightLine()
    if name == "oracle":
        if task is None:
            raise ValueError(
                "potential=oracle needs the map whose shortest way it knows: give the learner "
                "its task (--task, VOXSHAPE_TASK), or use potential=straight_line"
            )
        return ShortestWay(task)
    if name == "none":
        return None
    raise ValueError(f"potential={name!r}: one of straight_line, oracle, none")

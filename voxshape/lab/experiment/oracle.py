"""The experiments' oracle potential: the ceiling of what a potential over places can carry.

Phi(x, y) = minus the map's true shortest-path distance to the goal (the simulated teacher's
geodesic distance), given to the learner in place of the straight line
(`--set potential=oracle`). Never on a live robot: it knows the map."""

from __future__ import annotations

from voxshape.world.geodesic import GeodesicDistance
from voxshape.world.maps import Map


class OraclePotential:
    def __init__(self, m: Map) -> None:
        self.distance = GeodesicDistance(m)

    def value(self, x: float, y: float) -> float:
        """Minus the shortest-path distance to the goal, in metres."""
        return -self.distance(x, y)

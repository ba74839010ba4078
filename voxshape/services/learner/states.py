"""States born incrementally from sensor readings (Pearson prototypes), plus goal features.

A reading is summarised as a sensor vector: the nearest laser range in each of
`laser_sectors` sectors, then the sonar ranges. Its Pearson correlation with every stored
prototype is computed; if the best is below the threshold, the reading becomes a new
prototype. Pearson's correlation compares shapes, not distances, so sensors alone cannot
tell where the goal is, nor how near the walls are: the state is (prototype, near, goal-bearing
bin, goal-distance bin, goal sector), where `near` has a bit for each of the laser's right,
front and left thirds with something within `near_range` (0 when off), the goal bins are 0
without `goal_features`, and the goal sector (which side of the goal the robot is on, from
odometry: `goal_sectors`) is 0 when off. Prototypes are used with representation="pearson";
otherwise one prototype stands for all. A state is its key's index, a row of Q.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from functools import cache
from typing import Protocol

import numpy as np

from voxshape.services.learner.config import LearnerConfig

CLEAR = -1  # the prototype of readings with nothing within clear_range


@cache
def _sector_starts(n: int, sectors: int) -> np.ndarray:
    """Where each of `sectors` near-equal sectors of n beams starts (as np.array_split)."""
    sizes = [len(a) for a in np.array_split(np.zeros(n), sectors)]
    return np.cumsum([0, *sizes[:-1]])


def _sector_minima(laser: np.ndarray, sectors: int) -> np.ndarray:
    """The nearest range in each sector of the laser, right to left."""
    return np.minimum.reduceat(laser, _sector_starts(len(laser), sectors))


def _bin(angle: float, n: int) -> int:
    """The one of n equal sectors an angle falls in, the first centred on 0."""
    return math.floor((angle + math.pi / n) / (2 * math.pi / n)) % n


class Percept(Protocol):
    """What the learner reads of an observation (protocol.Observation or a sim Reading)."""

    laser: np.ndarray | tuple[float, ...]
    sonar: np.ndarray | tuple[float, ...]
    goal_distance: float
    goal_bearing: float
    theta: float  # heading, radians in the world frame (odometry)


class StateSpace:
    def __init__(self, config: LearnerConfig) -> None:
        self.config = config
        self.prototypes: list[np.ndarray] = []  # centred, unit-norm sensor vectors
        # (prototype, near, bearing, distance, sector)
        self.keys: dict[tuple[int, int, int, int, int], int] = {}
        self.key_of: list[tuple[int, int, int, int, int]] = []  # each state's key
        self._matrix = np.zeros((0, 0))

    def __len__(self) -> int:
        return len(self.keys)

    @property
    def reach(self) -> float | None:
        """How far the sensors must see for a state: the near range when the near bits are
        all that reads them (0 when nothing does), else their full range (None)."""
        if self.config.representation == "pearson":
            return None
        return self.config.near_range or 0.0

    def sensor_vector(self, p: Percept) -> np.ndarray:
        laser = np.asarray(p.laser, dtype=float)
        parts = [_sector_minima(laser, self.config.laser_sectors)]
        if self.config.use_sonar:
            parts.append(np.asarray(p.sonar, dtype=float))
        return np.concatenate(parts)

    def near_bits(self, p: Percept) -> int:
        if self.config.near_range is None:
            return 0
        minima = _sector_minima(np.asarray(p.laser, dtype=float), self.config.near_sectors)
        near = self.config.near_range
        return sum(1 << i for i, m in enumerate(minima.tolist()) if m < near)

    def goal_bins(self, p: Percept) -> tuple[int, int, int]:
        """(bearing, distance, sector): where the goal is seen from the robot, how far, and on
        which side of the goal the robot is (the world-frame direction from the goal to the
        robot, from the heading and the bearing: 0 without `goal_sectors`)."""
        c = self.config
        if not c.goal_features:
            return 0, 0, 0
        bearing = _bin(p.goal_bearing, c.bearing_bins)
        distance = bisect_right(c.distance_edges, p.goal_distance)
        sector = _bin(p.theta + p.goal_bearing + math.pi, c.goal_sectors) if c.goal_sectors else 0
        return bearing, distance, sector

    def classify(self, p: Percept) -> tuple[int, int | None]:
        """The state of a percept, and the state it was born from (None if not new)."""
        prototype, neighbour_prototype = 0, None  # without prototypes, one for all
        if self.config.representation == "pearson":
            vector = self.sensor_vector(p)
            clear_range = self.config.clear_range
            if clear_range is not None and vector.min() >= clear_range:
                prototype = CLEAR
            else:
                centred = vector - vector.mean()
                norm = np.linalg.norm(centred)
                unit = centred / norm if norm > 1e-9 else centred
                prototype, neighbour_prototype = self._match(unit)
        key = (prototype, self.near_bits(p), *self.goal_bins(p))
        if key in self.keys:
            return self.keys[key], None
        self.keys[key] = len(self.keys)
        self.key_of.append(key)
        # The nearest existing state: same bits and bins, best-matching prototype.
        parent = (
            self.keys.get((neighbour_prototype, *key[1:]))
            if neighbour_prototype is not None
            else None
        )
        return self.keys[key], parent

    def _match(self, unit: np.ndarray) -> tuple[int, int | None]:
        """(prototype index, best other prototype when a new one was born)."""
        if self.prototypes:
            correlations = self._matrix @ unit  # Pearson: dot product of centred unit vectors
            best = int(np.argmax(correlations))
            if correlations[best] >= self.config.pearson_threshold:
                return best, None
        else:
            best = None
        self.prototypes.append(unit)
        self._matrix = np.array(self.prototypes)
        return len(self.prototypes) - 1, best

    def restore(self, prototypes: list, keys: list) -> None:
        self.prototypes = [np.asarray(p, dtype=float) for p in prototypes]
        self._matrix = np.array(self.prototypes) if self.prototypes else np.zeros((0, 0))
        self.keys = {tuple(int(v) for v in k): i for i, k in enumerate(keys)}
        self.key_of = list(self.keys)

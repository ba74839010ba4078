"""What the learner sees of a percept: a state as the indices of its active binary features.

Q and the teacher's advice H are linear over them (Sutton & Barto, chapters 9-12): a value
of a state is the mean of its active features' weights, so one update moves it as a table's
entry would move, and every state sharing a feature a little. A `State` names two sets of
features, one for each: `q` (Q and its traces) and `advice` (H). Each `representation` fills
them its own way:

- "keys", the default: one feature per key (near bits and goal bins, states.py), with the
  advice tiles (coarser keys, `advice_generalization`) as further features of H alone;
- "tiles": tile coding of the pose the observation carries, `tilings` offset grids of
  `tile_width` metres by `heading_tiles` headings (Sutton's asymmetric offsets), plus the
  key as `key_tilings` more features; Q and H share them, so what a teacher says at one
  place speaks for nearby places and headings more than for far ones (which share the key);
- "pearson": the paper's states, "keys" with Pearson prototypes of the sensor readings.

Features are numbered as they are first seen (arrays grow); `coordinates` lists what each
index stands for, so a checkpoint restores the numbering exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from voxshape.services.learner.config import KEY_FIELDS, LearnerConfig
from voxshape.services.learner.states import Percept, StateSpace


class PosePercept(Percept, Protocol):
    x: float  # metres, world frame (odometry)
    y: float


@dataclass(frozen=True, eq=False)
class State:
    """The active features of a state, for Q and H (indices into their arrays), and
    what the robot sees there (its key: a policy action is held while it stays the same)."""

    q: np.ndarray
    advice: np.ndarray
    view: int


class Numbering:
    """Indices given to coordinates in the order they are first seen."""

    def __init__(self) -> None:
        self.index: dict[tuple, int] = {}

    def __len__(self) -> int:
        return len(self.index)

    def __call__(self, coordinates: list[tuple]) -> np.ndarray:
        index = self.index
        return np.array([index.setdefault(c, len(index)) for c in coordinates], dtype=np.int64)

    def restore(self, coordinates: list[tuple]) -> None:
        self.index = {tuple(c): i for i, c in enumerate(coordinates)}


def pose_tiles(x: float, y: float, heading: float, tilings: int, headings: int) -> list[tuple]:
    """The tile of (x, y, heading), in units of tiles, in each of `tilings` offset grids, as
    Sutton's tiles3 `tileswrap`: tiling t is offset by t/tilings of a tile in x, 3t/tilings
    in y and 5t/tilings in heading, which wraps around after `headings` tiles."""
    n = tilings
    qx, qy, qh = math.floor(x * n), math.floor(y * n), math.floor(heading * n)
    return [(t, (qx + t) // n, (qy + 3 * t) // n, (qh + 5 * t) // n % headings) for t in range(n)]


class Representation(Protocol):
    def encode(self, p: PosePercept) -> tuple[State, int | None]:
        """The state of a percept, and for a new Q feature the one it starts from."""

    def __len__(self) -> int:
        """States (or features) seen so far."""

    sizes: tuple[int, int]  # features of Q and H so far
    reach: float | None  # how far the sensors must see (StateSpace.reach)

    def coordinates(self) -> dict[str, list]: ...

    def restore(self, saved: dict[str, list]) -> None: ...


class Tiles:
    """Tile coding of the pose (x, y, heading) plus the key of states.py, `key_tilings`
    times over (its weight); the key decides how long a policy action is held."""

    def __init__(self, config: LearnerConfig) -> None:
        self.config = config
        self.keys = StateSpace(config)  # near bits and goal bins, no prototypes
        self.numbering = Numbering()

    def __len__(self) -> int:
        return len(self.numbering)

    @property
    def sizes(self) -> tuple[int, int]:
        n = len(self.numbering)
        return n, n

    @property
    def reach(self) -> float | None:
        return self.keys.reach

    def encode(self, p: PosePercept) -> tuple[State, None]:
        c = self.config
        heading = (p.theta % math.tau) / math.tau * c.heading_tiles
        w = c.tile_width
        pose = pose_tiles(p.x / w, p.y / w, heading, c.tilings, c.heading_tiles)
        key = (self.keys.near_bits(p), *self.keys.goal_bins(p))
        keys = [("key", k, *key) for k in range(c.key_tilings)]
        x = self.numbering([*pose, *keys])
        return State(x, x, view=int(x[-1])), None

    def coordinates(self) -> dict[str, list]:
        return {"features": [list(c) for c in self.numbering.index]}

    def restore(self, saved: dict[str, list]) -> None:
        self.numbering.restore(saved["features"])


class Keys:
    """A feature per key of states.py (Pearson prototypes with "pearson"); H also reads
    the key's advice tiles."""

    def __init__(self, config: LearnerConfig) -> None:
        self.config = config
        self.space = StateSpace(config)
        self.ignored = [KEY_FIELDS.index(name) for name in config.advice_generalization]
        self.advice = Numbering()  # ("state", s) and (tiling, the key without a field)
        self.states: list[State] = []  # each state's features, made when it is born

    def __len__(self) -> int:
        return len(self.space)

    @property
    def sizes(self) -> tuple[int, int]:
        return len(self.space), len(self.advice)

    @property
    def reach(self) -> float | None:
        return self.space.reach

    def encode(self, p: PosePercept) -> tuple[State, int | None]:
        s, parent = self.space.classify(p)
        if s == len(self.states):
            self.states.append(self._state(s))
        state, c = self.states[s], self.config
        if not c.advice_place_tilings:
            return state, parent
        heading = (p.theta % math.tau) / math.tau * c.heading_tiles
        w = c.tile_width
        tiles = pose_tiles(p.x / w, p.y / w, heading, c.advice_place_tilings, c.heading_tiles)
        place = self.advice([("place", *t) for t in tiles])
        return State(state.q, np.concatenate([state.advice, place]), view=s), parent

    def _state(self, s: int) -> State:
        key = self.space.key_of[s]
        coarse = [(t, *key[:i], *key[i + 1 :]) for t, i in enumerate(self.ignored)]
        return State(
            np.array([s], dtype=np.int64),
            self.advice([("state", s), *coarse]),
            view=s,
        )

    def coordinates(self) -> dict[str, list]:
        return {
            "keys": [list(k) for k in self.space.key_of],
            "prototypes": [p.tolist() for p in self.space.prototypes],
            "advice": [list(c) for c in self.advice.index],
        }

    def restore(self, saved: dict[str, list]) -> None:
        self.space.restore(saved["prototypes"], saved["keys"])
        self.advice.restore(saved["advice"])
        self.states = [self._state(s) for s in range(len(self.space))]


def representation(config: LearnerConfig) -> Representation:
    return Tiles(config) if config.representation == "tiles" else Keys(config)

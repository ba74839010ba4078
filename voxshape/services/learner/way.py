"""The way to the goal as the robot believes it, place by place: its own guess (the
potential Phi, potential.py) and a person's words, weighed as evidence.

At a place p the guess says "the way is along g(p)", the unit gradient of Phi, held with
the weight kappa(p) (`guess_weight` votes, less where the guess has kept the robot stalled:
`stall_s` seconds of stall at a place halve it). Every word a person says is one vote about
a direction there (words.py: a judgement about the motion it judges, a command about the
heading it asks for, a dictated trace about the way it went); the votes add up in W(p), a
2-vector tile-coded over the place (8 offset grids of `way_tile_m` metres). The believed way
is kappa g + W, the mean direction of a von Mises prior around g updated by one vote per
word, and the progress of a move from p to p', in metres, is

    progress(p, p') = (kappa (Phi(p') - Phi(p)) + W . (p' - p)) / max(|kappa g + W|, kappa)

Where nobody spoke W = 0 and this is Phi's own rise; words that agree with the guess leave
its direction, and where the votes turn the way less than `dead_zone` degrees from g the
guess stands as it is: a lone slip, or a word about a detail, changes nothing. Votes that
contradict the guess where it stalls the robot turn the way theirs, there and not elsewhere.
Votes and stalls fade by `word_fade` each episode, so the robot's own Q takes over.
"""

from __future__ import annotations

import math

import numpy as np

from voxshape.services.learner.config import LearnerConfig
from voxshape.services.learner.potential import Place, Potential

TILINGS = 8  # offset grids of the votes and the stalls
EPS = 0.05  # metres: the step of the guess's numerical gradient
STALL_AFTER_S = 5.0  # the guess stalls the robot when Phi has not risen ...
STALL_RISE = 0.1  # ... this many metres for that long

Tile = tuple[int, int, int]


class Way:
    def __init__(self, guess: Potential | None, config: LearnerConfig) -> None:
        self.guess, self.config = guess, config
        self.votes: dict[Tile, np.ndarray] = {}  # W, a 2-vector per tile
        self.stalled: dict[Tile, float] = {}  # seconds the guess made no progress there
        self._agree = math.cos(math.radians(config.dead_zone))
        self._best = (-math.inf, 0.0)  # the episode's best Phi, and the seconds since

    # -- the evidence --------------------------------------------------------------------
    def vote(self, place: Place, direction: np.ndarray, weight: float) -> None:
        """A vote of `weight` (negative: against) for the unit `direction` at `place`."""
        change = weight * np.asarray(direction, dtype=float)
        for tile in self._tiles(place):
            self.votes[tile] = self.votes.get(tile, np.zeros(2)) + change

    def watch(self, place: Place, seconds: float, new_episode: bool) -> None:
        """The robot spent `seconds` at `place`: counted as a stall of the guess's there
        once Phi has not risen STALL_RISE metres for STALL_AFTER_S."""
        phi = self.phi(place)
        if new_episode or phi > self._best[0] + STALL_RISE:
            self._best = (phi, 0.0)
            return
        self._best = (self._best[0], self._best[1] + seconds)
        if self._best[1] >= STALL_AFTER_S - 1e-9:
            for tile in self._tiles(place):
                self.stalled[tile] = self.stalled.get(tile, 0.0) + seconds

    def fade(self) -> None:
        """An episode has ended: its votes and stalls count `word_fade` as much."""
        fade = self.config.word_fade
        for table in (self.votes, self.stalled):
            for tile in table:
                table[tile] *= fade

    # -- the belief ------------------------------------------------------------------------
    def W(self, place: Place) -> np.ndarray:
        """The votes at a place: the mean of its tiles'."""
        total = np.zeros(2)
        for tile in self._tiles(place):
            vote = self.votes.get(tile)
            if vote is not None:
                total += vote
        return total / TILINGS

    def kappa(self, place: Place) -> float:
        """The guess's weight at a place, lower where it has stalled the robot."""
        c = self.config
        if not c.stall_s:
            return c.guess_weight
        stalled = sum(self.stalled.get(t, 0.0) for t in self._tiles(place)) / TILINGS
        return c.guess_weight / (1.0 + stalled / c.stall_s)

    def phi(self, place: Place) -> float:
        """The guess's potential, metres (0 without one)."""
        return 0.0 if self.guess is None else self.guess.value(*place)

    def gradient(self, place: Place) -> np.ndarray:
        """The guess's unit gradient at a place (0 without one)."""
        if self.guess is None:
            return np.zeros(2)
        x, y = place
        value = self.guess.value
        g = np.array([value(x + EPS, y) - value(x - EPS, y), value(x, y + EPS) - value(x, y - EPS)])
        norm = float(np.hypot(*g))
        return g / norm if norm > 1e-12 else np.zeros(2)

    def progress(self, here: Place, there: Place, words: bool = True) -> float:
        """Metres of progress along the believed way from `here` to `there` (the module's
        docstring); `words=False`: along the guess alone."""
        rise = self.phi(there) - self.phi(here)
        W = self.W(here) if words and self.votes else None
        if W is None or not W.any():
            return rise
        kappa, g = self.kappa(here), self.gradient(here)
        believed = kappa * g + W
        norm = float(np.hypot(*believed))
        if g.any() and believed @ g > norm * self._agree:
            return rise  # turned less than the dead zone: the guess stands
        move = np.subtract(there, here)
        return float((kappa * rise + W @ move) / max(norm, kappa))

    def spoken_at(self, place: Place) -> bool:
        """Whether any word has left a vote here."""
        return bool(self.votes) and bool(self.W(place).any())

    def _tiles(self, place: Place) -> list[Tile]:
        n, w = TILINGS, self.config.way_tile_m
        qx, qy = math.floor(place[0] / w * n), math.floor(place[1] / w * n)
        return [(t, (qx + t) // n, (qy + 3 * t) // n) for t in range(n)]

    # -- checkpoints -----------------------------------------------------------------------
    def tables(self) -> dict[str, np.ndarray]:
        """The votes and the stalls as arrays (tile, then values)."""
        tiles = np.array(list(self.votes), dtype=np.int64).reshape(-1, 3)
        votes = np.array(list(self.votes.values())).reshape(-1, 2)
        stall_tiles = np.array(list(self.stalled), dtype=np.int64).reshape(-1, 3)
        stalls = np.array(list(self.stalled.values()), dtype=float)
        return {"vote_tiles": tiles, "votes": votes, "stall_tiles": stall_tiles, "stalls": stalls}

    def restore(self, arrays: dict[str, np.ndarray]) -> None:
        """The votes and the stalls `tables` saved."""
        votes = zip(arrays["vote_tiles"], arrays["votes"], strict=True)
        self.votes = {(int(t), int(x), int(y)): v.copy() for (t, x, y), v in votes}
        stalls = zip(arrays["stall_tiles"], arrays["stalls"], strict=True)
        self.stalled = {(int(t), int(x), int(y)): float(v) for (t, x, y), v in stalls}

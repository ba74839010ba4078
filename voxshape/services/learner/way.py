"""The way to the goal as the robot believes it, place by place: its own guess (the potential
Phi, by default the straight line) and a person's words, weighed as evidence.

At a place p the guess says "the way is along g(p)", the unit gradient of Phi, held with
the weight `guess_weight` (kappa, in words). Every word a person says is one vote about a
direction there: a judgement about the motion it judges (its displacement u over the judged
stretch: "good" votes +u, "bad" -u), a command about the heading it asks for, a dictated
trace about the way it went. The votes add up in W(p), tile-coded over the place. The
believed way is their sum with the guess, kappa g(p) + W(p) (the mean direction of a von
Mises prior around g updated by one vote per word), and the progress a move from p to p'
makes along it, in metres:

    progress(p, p') = (kappa (Phi(p') - Phi(p)) + W(p) . (p' - p)) / max(|kappa g(p) + W(p)|, kappa)

Where nobody spoke, W(p) = 0 and this is Phi's own rise; a word that agrees with the guess
leaves the direction as it was; a lone slip (a vote against g, kappa > 1) does not turn it;
words that contradict the guess again and again turn it their way, there and not elsewhere.
"""

from __future__ import annotations

import math

import numpy as np

from voxshape.services.learner.potential import Place, Potential

EPS = 0.05  # metres: the step of the guess's numerical gradient


class Way:
    def __init__(
        self, guess: Potential | None, weight: float, tilings: int, tile_width: float
    ) -> None:
        self.guess, self.kappa = guess, weight
        self.tilings, self.width = tilings, tile_width
        self.votes: dict[tuple[int, int, int], np.ndarray] = {}  # W, a 2-vector per tile
        self.stalled: dict[tuple[int, int, int], float] = {}  # seconds the guess made no progress
        self.stall_s = 0.0  # seconds of stall that halve the guess's weight (0: never)
        self.n_votes = 0.0
        self.agree_cos = 1.0  # cos of the dead zone: a way turned less than it is the guess's

    def _tiles(self, x: float, y: float) -> list[tuple[int, int, int]]:
        n, w = self.tilings, self.width
        qx, qy = math.floor(x / w * n), math.floor(y / w * n)
        return [(t, (qx + t) // n, (qy + 3 * t) // n) for t in range(n)]

    def W(self, place: Place) -> np.ndarray:
        """The votes at a place: the mean of its tiles'."""
        total = np.zeros(2)
        for tile in self._tiles(*place):
            vote = self.votes.get(tile)
            if vote is not None:
                total += vote
        return total / self.tilings

    def vote(self, place: Place, direction: np.ndarray, weight: float) -> None:
        """A vote of `weight` (negative: against) for the unit `direction` at `place`."""
        change = weight * direction
        for tile in self._tiles(*place):
            self.votes[tile] = self.votes.get(tile, np.zeros(2)) + change
        self.n_votes += abs(weight)

    def stall(self, place: Place, seconds: float) -> None:
        """The robot spent `seconds` at `place` without the guess seeing progress."""
        for tile in self._tiles(*place):
            self.stalled[tile] = self.stalled.get(tile, 0.0) + seconds

    def weight(self, place: Place) -> float:
        """kappa at a place: the guess's weight, lower where it has stalled the robot."""
        if not self.stall_s or not self.stalled:
            return self.kappa
        stalled = sum(self.stalled.get(t, 0.0) for t in self._tiles(*place)) / self.tilings
        return self.kappa / (1.0 + stalled / self.stall_s)

    def fade(self, votes: float, stalls: float) -> None:
        """An episode has ended: the votes and the stalls count that much less."""
        for tile in self.votes:
            self.votes[tile] *= votes
        for tile in self.stalled:
            self.stalled[tile] *= stalls

    def phi(self, place: Place) -> float:
        """The guess's potential, metres (0 without one)."""
        return 0.0 if self.guess is None else self.guess.value(*place)

    def gradient(self, place: Place) -> np.ndarray:
        """The guess's unit gradient at a place (0 without one)."""
        if self.guess is None:
            return np.zeros(2)
        x, y = place
        g = np.array(
            [
                self.guess.value(x + EPS, y) - self.guess.value(x - EPS, y),
                self.guess.value(x, y + EPS) - self.guess.value(x, y - EPS),
            ]
        )
        norm = float(np.hypot(*g))
        return g / norm if norm > 1e-12 else np.zeros(2)

    def progress(self, here: Place, there: Place, words: bool = True) -> float:
        """Metres of progress along the believed way from `here` to `there` (the module's
        docstring); `words=False`: along the guess alone."""
        rise = self.phi(there) - self.phi(here)
        W = self.W(here) if words and self.votes else None
        if W is None or not W.any():
            return rise
        kappa = self.weight(here)
        g = self.gradient(here)
        believed = kappa * g + W
        norm = float(np.hypot(*believed))
        if g.any() and norm and believed @ g > norm * self.agree_cos:
            return rise  # the words turn the way less than the dead zone: the guess's own
        move = np.subtract(there, here)
        return float((kappa * rise + W @ move) / max(norm, kappa))

    def direction(self, place: Place) -> np.ndarray:
        """The believed way's unit direction at a place (0 where there is none)."""
        believed = self.weight(place) * self.gradient(place) + self.W(place)
        norm = float(np.hypot(*believed))
        return believed / norm if norm > 1e-12 else np.zeros(2)

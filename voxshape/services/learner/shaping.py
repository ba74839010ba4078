"""Where the teacher's words go: the g and h of Algorithm 1, as a rule the learner is given
(as Sutton & Barto give SARSA its trace rule).

- `Additive` (shaping="additive", the paper's): R = R_RL + R_U. h's bonus joins the reward of
  the step the teacher chose, g's f moves Q where the arbiter credits it, and a replayed trace
  runs the SARSA update like the robot's own steps.
- `ActionBias` (the default, TAMER+RL's action biasing): the words go to a table H of their
  own (advice.py); the policy ranks Q + beta bias_decay^episode H, and Q learns from R_RL
  alone, on the robot's own steps and a replayed trace's (whose commands earn no bonus: a
  dictated trace teaches by where it went, not as advice).

Both leave the potential Phi (potential.py) as it is: words do not move it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from voxshape.services.learner.advice import Advice, add_rows
from voxshape.services.learner.config import LearnerConfig
from voxshape.services.learner.features import State


class Shaping(Protocol):
    def chosen(
        self, r: float, s: State, weights: np.ndarray, bonus: float, replayed: bool
    ) -> float:
        """h(r, a): the reward of a step whose action the teacher chose in s (`replayed`:
        in a trace replayed)."""

    def credit(self, Q: np.ndarray, states: Sequence[State], changes: np.ndarray) -> None:
        """g's f (or h's bonus) credited after the fact: each state's change, in order."""

    def ranked(self, q: np.ndarray, s: State, episode: int) -> np.ndarray:
        """What the policy ranks the actions of s by, given Q(s, .), after `episode`
        episodes."""


class Additive:
    def __init__(self, config: LearnerConfig, taught: Advice) -> None:
        pass

    def chosen(
        self, r: float, s: State, weights: np.ndarray, bonus: float, replayed: bool
    ) -> float:
        return r + bonus

    def credit(self, Q: np.ndarray, states: Sequence[State], changes: np.ndarray) -> None:
        add_rows(Q, [s.q for s in states], changes)

    def ranked(self, q: np.ndarray, s: State, episode: int) -> np.ndarray:
        return q


class ActionBias:
    def __init__(self, config: LearnerConfig, taught: Advice) -> None:
        self.alpha, self.beta, self.taught = config.alpha, config.bias_weight, taught

    def chosen(
        self, r: float, s: State, weights: np.ndarray, bonus: float, replayed: bool
    ) -> float:
        if not replayed:  # a dictated trace teaches Q, by its own steps' rewards
            self.taught.advise([s], (self.alpha * bonus * weights)[None, :])
        return r

    def credit(self, Q: np.ndarray, states: Sequence[State], changes: np.ndarray) -> None:
        self.taught.advise(states, changes)

    def ranked(self, q: np.ndarray, s: State, episode: int) -> np.ndarray:
        return q + self.beta * self.taught.weighed(s, episode)


class WayOnly(Additive):
    """shaping="way": words are votes about the way (way.py), not rewards or a bias."""

    def chosen(
        self, r: float, s: State, weights: np.ndarray, bonus: float, replayed: bool
    ) -> float:
        return r

    def credit(self, Q: np.ndarray, states: Sequence[State], changes: np.ndarray) -> None:
        pass


SHAPINGS: dict[str, type[Additive] | type[ActionBias]] = {
    "additive": Additive,
    "action_bias": ActionBias,
    "way": WayOnly,
}

"""Where the teacher's words go: the g and h of Algorithm 1, as a rule the learner is given
(as Sutton & Barto give SARSA its trace rule).

- `Additive` (shaping="additive", the paper's): R = R_RL + R_U. h's bonus joins the reward of
  the step the teacher chose, g's f moves Q where the arbiter credits it, and a replayed trace
  runs the SARSA update like the robot's own steps.
- `ActionBias` (the default, TAMER+RL's action biasing): the words go to a table H of their
  own and a replayed trace's commands to T (advice.py); the policy ranks
  Q + beta (T + bias_decay^episode H), Q learns from R_RL alone, on the robot's own steps.

Both leave the potential Phi to the learner: it moves with every word whatever the rule.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from services.learner.advice import Advice, add_rows
from services.learner.config import LearnerConfig
from services.learner.features import State


class Shaping(Protocol):
    replays_learn_q: bool  # a replayed trace runs the Q update (else it teaches the words)

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
    replays_learn_q = True

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
    replays_learn_q = False

    def __init__(self, config: LearnerConfig, taught: Advice) -> None:
        self.alpha, self.beta, self.taught = config.alpha, config.bias_weight, taught

    def chosen(
        self, r: float, s: State, weights: np.ndarray, bonus: float, replayed: bool
    ) -> float:
        self.taught.advise([s], (self.alpha * bonus * weights)[None, :], traced=replayed)
        return r

    def credit(self, Q: np.ndarray, states: Sequence[State], changes: np.ndarray) -> None:
        self.taught.advise(states, changes)

    def ranked(self, q: np.ndarray, s: State, episode: int) -> np.ndarray:
        return q + self.beta * self.taught.weighed(s, episode)


SHAPINGS: dict[str, type[Additive] | type[ActionBias]] = {
    "additive": Additive,
    "action_bias": ActionBias,
}

"""What the teacher's words leave in the learner besides Q: H, the action bias the policy
ranks actions with (TAMER+RL, shaping="action_bias").

The policy weighs bias_decay^episode H: the words' bias fades as the robot's own Q learns
(Knox & Stone's annealed action biasing), so advice that was nearly right does not hold the
robot off a faster way.

H is linear over the state's binary features, as Q is (features.py): H(s) is the mean of
the rows of its advice features (the key, its coarser tiles and tilings of the pose)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from voxshape.services.learner.actions import N_ACTIONS
from voxshape.services.learner.config import LearnerConfig
from voxshape.services.learner.features import State


class Advice:
    """H, grown with the features, moved by the teacher's words."""

    def __init__(self, config: LearnerConfig) -> None:
        self.config = config
        self.H = np.zeros((0, N_ACTIONS))  # the words' action bias, a row per feature

    def weighed(self, s: State, episode: int) -> np.ndarray:
        """bias_decay^episode H(s, .): the bias the policy weighs after `episode` episodes."""
        fade = self.config.bias_decay**episode
        return fade * self.H[s.advice].sum(axis=0) / len(s.advice)

    def advise(self, states: Sequence[State], changes: np.ndarray) -> None:
        """H(s) += change for each state and its change (rows), in order."""
        add_rows(self.H, [s.advice for s in states], changes)

    def grow(self, n_advice: int) -> None:
        """Rows for new features, at 0."""
        if n_advice > len(self.H):
            self.H = np.vstack([self.H, np.zeros((n_advice - len(self.H), N_ACTIONS))])


def add_rows(table: np.ndarray, rows: list[np.ndarray], changes: np.ndarray) -> None:
    """table[r] += change for every feature r of each state's rows, in order."""
    counts = [len(r) for r in rows]
    np.add.at(table, np.concatenate(rows), np.repeat(changes, counts, axis=0))

"""What the teacher's words leave in the learner besides Q: H, the action bias the policy ranks
actions with (TAMER+RL, shaping="action_bias"), T, the same bias taught by replayed traces,
and Phi, the potential the words imply (potential-based shaping: F = gamma^k Phi(s') -
Phi(s), which keeps the optimum).

The policy weighs T + bias_decay^episode H: the words' bias fades as the robot's own Q
learns (Knox & Stone's annealed action biasing), so advice that was nearly right does not
hold the robot off a faster way; a dictated trace is the way, and its bias stays.

All are linear over the state's binary features, as Q is (features.py): H(s) and T(s) are
the means of the rows of its advice features, Phi(s) the mean of its place features."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from services.learner.actions import N_ACTIONS
from services.learner.config import LearnerConfig
from services.learner.features import State


class Advice:
    """H, T and Phi, grown with the features, moved by the teacher's words and traces."""

    def __init__(self, config: LearnerConfig) -> None:
        self.config = config
        self.H = np.zeros((0, N_ACTIONS))  # the words' action bias, a row per feature
        self.T = np.zeros((0, N_ACTIONS))  # the replayed traces' action bias, alike
        self.Phi = np.zeros(0)  # the potential, a value per place feature

    def weighed(self, s: State, episode: int) -> np.ndarray:
        """T(s, .) + bias_decay^episode H(s, .): the bias the policy weighs after `episode`
        episodes."""
        fade = self.config.bias_decay**episode
        return (self.T[s.advice].sum(axis=0) + fade * self.H[s.advice].sum(axis=0)) / len(s.advice)

    def phi(self, s: State) -> float:
        """Phi(s) (0 when potential_rate is 0)."""
        if not self.config.potential_rate:
            return 0.0
        return float(self.Phi[s.place].sum()) / len(s.place)

    def advise(self, states: Sequence[State], changes: np.ndarray, traced: bool = False) -> None:
        """H(s) (T(s) for a replayed trace's) += change for each state and its change (rows),
        in order."""
        add_rows(self.T if traced else self.H, [s.advice for s in states], changes)

    def toward(
        self, states: Sequence[State], e_k: Sequence[float], weight: float, f: float
    ) -> None:
        """Phi(s_j) moved towards the word's reward f, by its share w e_k(s_j)."""
        rate = self.config.potential_rate
        for s, trace in zip(states, e_k, strict=True):
            self.Phi[s.place] += rate * weight * trace * (f - self.phi(s))

    def grow(self, n_advice: int, n_place: int) -> None:
        """Rows for new features, at 0."""
        if n_advice > len(self.H):
            self.H = np.vstack([self.H, np.zeros((n_advice - len(self.H), N_ACTIONS))])
            self.T = np.vstack([self.T, np.zeros((n_advice - len(self.T), N_ACTIONS))])
        if n_place > len(self.Phi):
            self.Phi = np.concatenate([self.Phi, np.zeros(n_place - len(self.Phi))])


def add_rows(table: np.ndarray, rows: list[np.ndarray], changes: np.ndarray) -> None:
    """table[r] += change for every feature r of each state's rows, in order."""
    counts = [len(r) for r in rows]
    np.add.at(table, np.concatenate(rows), np.repeat(changes, counts, axis=0))

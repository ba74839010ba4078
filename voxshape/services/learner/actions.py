"""From Q-values to what the robot does: epsilon-greedy over the discrete actions, or their
Q-weighted blend sent as one continuous (v, omega) (after Millan et al. 2002)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from voxshape.protocol import ACTION_NAMES
from voxshape.services.learner.config import LearnerConfig

N_ACTIONS = len(ACTION_NAMES)


@dataclass(frozen=True)
class Decision:
    weights: np.ndarray  # per discrete action (ACTION_NAMES order), summing to 1
    v: float
    omega: float
    chooser: str  # "policy" or "teacher"

    @property
    def discrete(self) -> int:
        """The action this decision is mostly made of."""
        return int(np.argmax(self.weights))


class ActionSet:
    def __init__(self, config: LearnerConfig) -> None:
        self.config = config
        self.velocity = np.array([config.velocities[name] for name in ACTION_NAMES])
        self.allowed = np.array([name in config.policy_actions for name in ACTION_NAMES])
        # The turn that undoes each turn on the spot (left <-> right): same speed, -omega.
        self.undoing = {
            i: j
            for i, (v, omega) in enumerate(self.velocity)
            for j, (v2, omega2) in enumerate(self.velocity)
            if v == v2 == 0 and omega != 0 and omega2 == -omega
        }
        # The actions the policy may choose, all of them or all but a barred one.
        self._allowed = {
            barred: np.flatnonzero(self.allowed & (np.arange(N_ACTIONS) != barred))
            for barred in (None, *range(N_ACTIONS))
        }

    def allowed_but(self, barred: int | None) -> np.ndarray:
        """The indices of the actions the policy may choose, but the barred one."""
        return self._allowed[barred]

    def one_hot(self, index: int, chooser: str = "policy") -> Decision:
        weights = np.zeros(N_ACTIONS)
        weights[index] = 1.0
        v, omega = self.velocity[index]
        return Decision(weights, float(v), float(omega), chooser)

    def choose(
        self,
        q: np.ndarray,
        epsilon: float,
        rng: np.random.Generator,
        barred: int | None = None,
    ) -> Decision:
        """Epsilon-greedy: a random allowed action, else the greedy one or the blend; never
        the `barred` one. (A random pick among n is rng.integers(n), as rng.choice draws.)"""
        allowed = self._allowed[barred]
        if rng.random() < epsilon:
            return self.one_hot(int(allowed[rng.integers(len(allowed))]))
        q_allowed = q[allowed]
        if not self.config.blend:
            best = allowed[q_allowed == q_allowed.max()]
            return self.one_hot(int(best[rng.integers(len(best))]))  # ties broken at random
        spread = q_allowed.max() - q_allowed.min()
        if spread < 1e-9:  # nothing learnt here yet: one action, not a mix that cancels out
            return self.one_hot(int(allowed[rng.integers(len(allowed))]))
        # The temperature is relative to the spread of Q in this state, so the blend has the
        # same sharpness whatever the scale of the rewards.
        z = (q_allowed - q_allowed.max()) / (self.config.temperature * spread)
        weights = np.zeros(N_ACTIONS)
        weights[allowed] = np.exp(z) / np.exp(z).sum()
        v, omega = weights @ self.velocity
        return Decision(weights, float(v), float(omega), "policy")

"""When has the robot learnt the task, and how long did it take? Defined here only.

Converged: the last K episodes (config.converge_episodes) all reached the goal, steadily (the
slowest of them within (1 + config.converge_margin) times the fastest) and, when the map's
shortest time is given, each within config.converge_slack times that: three equally slow
wanderings into the goal are not a learnt task. (Measured against the K episodes themselves,
not the fastest ever: one lucky start would otherwise hold a steady policy back for good.)
Learning time: the robot's simulated seconds over all episodes up to and including the one
that converged (the paper timed its robot, not the computer). Also counted: episodes, and
the teacher's interventions (feedback and commands).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from voxshape.services.learner.config import LearnerConfig
from voxshape.world.maps import Map


@dataclass(frozen=True)
class EpisodeResult:
    outcome: str  # goal, collision, timeout
    steps: int
    sim_seconds: float
    interventions: int = 0


@dataclass
class Convergence:
    config: LearnerConfig
    shortest_s: float | None = None  # the map's shortest time to the goal (Map.shortest_time)
    episodes: list[EpisodeResult] = field(default_factory=list)
    converged_at: int | None = None  # index of the episode that converged

    def add(self, episode: EpisodeResult) -> bool:
        """Records a finished episode; True once converged."""
        self.episodes.append(episode)
        if self.converged_at is None and self._converged_now():
            self.converged_at = len(self.episodes) - 1
        return self.converged

    def _converged_now(self) -> bool:
        k, margin = self.config.converge_episodes, self.config.converge_margin
        last = self.episodes[-k:]
        if len(last) < k or any(e.outcome != "goal" for e in last):
            return False
        steps = [e.steps for e in last]
        bound = (
            math.inf if self.shortest_s is None else self.config.converge_slack * self.shortest_s
        )
        return max(steps) <= (1 + margin) * min(steps) and all(e.sim_seconds <= bound for e in last)

    def rule(self) -> str:
        """The rule in words, for reports."""
        c = self.config
        text = (
            f"{c.converge_episodes} goal episodes in a row, the slowest within "
            f"{c.converge_margin:.0%} of the fastest"
        )
        if self.shortest_s is not None:
            text += f", each within {c.converge_slack:g}x the map's shortest time"
            text += f" ({self.shortest_s:.1f} s)"
        return text

    @property
    def converged(self) -> bool:
        return self.converged_at is not None

    def _until(self) -> list[EpisodeResult]:
        end = self.converged_at + 1 if self.converged else len(self.episodes)
        return self.episodes[:end]

    @property
    def learning_time(self) -> float:
        """Simulated seconds until convergence (all episodes so far if not converged)."""
        return sum(e.sim_seconds for e in self._until())

    @property
    def n_episodes(self) -> int:
        return len(self._until())

    @property
    def interventions(self) -> int:
        return sum(e.interventions for e in self._until())


def convergence_on(m: Map, config: LearnerConfig) -> Convergence:
    """The convergence rule for a map: its shortest time bounds the converged episodes."""
    return Convergence(config, m.shortest_time(config.top_speed))

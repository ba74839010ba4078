"""When has the robot learnt the task, and how long did it take? Defined here only.

Converged: the last K episodes (config.converge_episodes) all reached the goal, each in at most
(1 + config.converge_margin) times the fewest steps of any goal episode so far.
Learning time: the robot's simulated seconds over all episodes up to and including the one
that converged (the paper timed its robot, not the computer). Also counted: episodes, and
the teacher's interventions (feedback and commands).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from services.learner.config import LearnerConfig


@dataclass(frozen=True)
class Episode:
    outcome: str  # goal, collision, timeout
    steps: int
    sim_seconds: float
    interventions: int = 0


@dataclass
class Convergence:
    config: LearnerConfig
    episodes: list[Episode] = field(default_factory=list)
    converged_at: int | None = None  # index of the episode that converged

    def add(self, episode: Episode) -> bool:
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
        best = min(e.steps for e in self.episodes if e.outcome == "goal")
        return all(e.steps <= (1 + margin) * best for e in last)

    @property
    def converged(self) -> bool:
        return self.converged_at is not None

    def _until(self) -> list[Episode]:
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

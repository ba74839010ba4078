"""In-process training: the simulator core and the learner core stepped directly, no bus.

Fast and deterministic for a seed; the experiments (and `voxshape train`) build on it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from services.learner.config import LearnerConfig
from services.learner.convergence import Convergence, EpisodeResult
from services.learner.sarsa import Learner
from services.learner.traces import TraceBook
from services.sim.maps import Map, load_map
from services.sim.task import SimConfig, Simulation


@dataclass
class TrainResult:
    task: str
    seed: int
    converged: bool
    episodes: int
    learning_time: float  # simulated seconds until convergence
    steps: int
    states: int
    history: list[EpisodeResult]


def train(
    task: str,
    seed: int,
    config: LearnerConfig | None = None,
    max_episodes: int = 500,
    sim_config: SimConfig | None = None,
    on_episode: Callable[[EpisodeResult, Learner], None] | None = None,
    traces: TraceBook | None = None,
) -> TrainResult:
    """SARSA(lambda) without a live teacher until convergence or `max_episodes`; with
    `traces`, learning first (and every `config.replay_every` episodes) from them."""
    config = config or LearnerConfig()
    sim = Simulation(load_map(task), ("robot",), sim_config, seed=seed)
    learner = Learner(config, seed=seed)
    progress = convergence_on(load_map(task), config)
    steps = 0
    try:
        for episode in range(max_episodes):
            if traces and episode == 0:
                traces.replay(learner)
            elif traces:
                traces.replay_if_due(learner)
            reading = sim.reset("robot")
            decision = learner.step(reading)
            while decision is not None:
                reading = sim.step({"robot": (decision.v, decision.omega)})["robot"]
                decision = learner.step(reading)
            steps += reading.episode_step
            episode = EpisodeResult(
                reading.outcome,
                reading.episode_step,
                reading.episode_step * sim.config.control_period,
            )
            if on_episode is not None:
                on_episode(episode, learner)
            if progress.add(episode):
                break
    finally:
        sim.close()
    return TrainResult(
        task,
        seed,
        progress.converged,
        progress.n_episodes,
        progress.learning_time,
        steps,
        len(learner.features),
        progress.episodes,
    )


def convergence_on(m: Map, config: LearnerConfig) -> Convergence:
    """The convergence rule for a map: its shortest time bounds the converged episodes."""
    return Convergence(config, m.shortest_time(config.top_speed))

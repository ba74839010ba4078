"""In-process training: the simulator core and the learner core stepped directly, no bus;
and `voxshape train`, plain SARSA(lambda) for a seed (no teacher).

Fast and deterministic for a seed; the experiments build on it.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace

from tqdm import tqdm

from services.learner.config import LearnerConfig, add_settings_argument, with_settings
from services.learner.convergence import EpisodeResult, convergence_on
from services.learner.sarsa import Learner
from services.learner.traces import TraceBook
from services.sim.task import SimConfig, Simulation
from services.world.maps import load_map


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


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--task", default="1", help="task number (1-4) or map file")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-episodes", type=int, default=500)
    parser.add_argument(
        "--no-goal-features",
        action="store_true",
        help="states from the sensors alone (no goal bearing and distance)",
    )
    parser.add_argument(
        "--blend",
        action="store_true",
        help="send the Q-weighted blend of the actions, not one action",
    )
    add_settings_argument(parser)
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace) -> int:
    base = replace(LearnerConfig(), goal_features=not args.no_goal_features, blend=args.blend)
    config = with_settings(args.set, base)
    with tqdm(total=args.max_episodes, unit="episode", disable=args.json, leave=False) as bar:

        def on_episode(episode: object, learner: object) -> None:
            bar.update(1)
            bar.set_postfix(
                outcome=episode.outcome, steps=episode.steps, states=len(learner.features)
            )

        result = train(args.task, args.seed, config, args.max_episodes, on_episode=on_episode)
    summary = {
        "task": result.task,
        "seed": result.seed,
        "converged": result.converged,
        "episodes": result.episodes,
        "learning_time_s": round(result.learning_time, 1),
        "learning_time_min": round(result.learning_time / 60, 2),
        "steps": result.steps,
        "states": result.states,
        "goals": sum(e.outcome == "goal" for e in result.history),
        "config": asdict(config) if args.json else None,
    }
    if args.json:
        print(json.dumps(summary))
    else:
        state = "converged" if result.converged else "did NOT converge"
        print(
            f"task {result.task}, seed {result.seed}: {state} after {result.episodes} "
            f"episodes, learning time {summary['learning_time_min']} min of robot time, "
            f"{result.states} states, {summary['goals']} goals in {len(result.history)} "
            "episodes"
        )
    return 0

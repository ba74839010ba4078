"""`voxshape train`: plain SARSA(lambda) for a task and a seed, no teacher: the experiments'
in-process run (inprocess.py) in the `rl` setting, with a progress bar and a summary."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict

from tqdm import tqdm

from voxshape.lab.experiment.inprocess import RunSpec
from voxshape.lab.experiment.inprocess import run as run_spec
from voxshape.services.learner.config import add_settings_argument, with_settings
from voxshape.services.learner.convergence import EpisodeResult
from voxshape.services.learner.sarsa import Learner
from voxshape.world.robot import CONTROL_PERIOD_S


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--task", default="1", help="task number (1-4) or map file")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-episodes", type=int, default=500)
    add_settings_argument(parser)
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace) -> int:
    config = with_settings(args.set)  # a bad --set is refused before the run
    spec = RunSpec(args.task, "rl", args.seed, args.max_episodes, learner=tuple(args.set))
    with tqdm(total=args.max_episodes, unit="episode", disable=args.json, leave=False) as bar:

        def on_episode(episode: EpisodeResult, learner: Learner) -> None:
            bar.update(1)
            bar.set_postfix(
                outcome=episode.outcome, steps=episode.steps, states=len(learner.states)
            )

        result = run_spec(spec, on_episode=on_episode)
    summary = {
        "task": result.task,
        "seed": result.seed,
        "converged": result.converged,
        "episodes": result.episodes,
        "learning_time_s": result.learning_time_s,
        "learning_time_min": round(result.learning_time_s / 60, 2),
        "steps": round(sum(result.durations_s) / CONTROL_PERIOD_S),
        "states": result.states,
        "goals": result.outcomes.count("goal"),
        "config": asdict(config) if args.json else None,
    }
    if args.json:
        print(json.dumps(summary))
        return 0
    state = "converged" if result.converged else "did NOT converge"
    print(
        f"task {result.task}, seed {result.seed}: {state} after {result.episodes} episodes, "
        f"learning time {summary['learning_time_min']} min of robot time, {result.states} "
        f"states, {summary['goals']} goals in {len(result.outcomes)} episodes"
    )
    return 0

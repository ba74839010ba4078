"""`voxshape train`: plain SARSA(lambda) in one process (no bus, no teacher), for a seed."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict, replace

from tqdm import tqdm

from services.learner.config import LearnerConfig, add_settings_argument, with_settings
from services.learner.train import train


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

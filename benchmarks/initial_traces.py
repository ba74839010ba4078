"""What initial traces change: the simulated teacher (services/teacher/simulated/) dictates a few
episodes along the map's shortest path (commands only, as a person would), then SARSA(lambda)
trains with those traces replayed (before learning and every `replay_every` episodes) and
without them.

    .venv/bin/python benchmarks/initial_traces.py --task 2 --traces 3 --seeds 3
"""

from __future__ import annotations

import argparse

from services.experiment.dictation import dictate
from services.experiment.train import train
from services.learner.config import LearnerConfig
from services.world.maps import load_map


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--task", default="2")
    parser.add_argument("--traces", type=int, default=3)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--max-episodes", type=int, default=300)
    args = parser.parse_args()
    book = dictate(load_map(args.task), args.traces)
    for episode in book.episodes:
        print(f"dictated trace: {episode[-1][0].outcome} in {len(episode) - 1} steps")
    print("| traces | seed | converged | episodes | goals reached | states |")
    print("|---|---|---|---|---|---|")
    for traces in (book, None):
        for seed in range(args.seeds):
            r = train(args.task, seed, LearnerConfig(), args.max_episodes, traces=traces)
            goals = sum(e.outcome == "goal" for e in r.history)
            print(
                f"| {len(book.episodes) if traces else 0} | {seed} | {r.converged} | "
                f"{r.episodes} | {goals} | {r.states} |",
                flush=True,
            )


if __name__ == "__main__":
    main()

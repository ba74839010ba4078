"""Plain SARSA(lambda) (no teacher) on every task and several seeds, with and without the
goal-relative state features: episodes and learning time to convergence.

    .venv/bin/python benchmarks/plain_rl.py --seeds 3 --max-episodes 150 [--blend]
        [--goal-features on,off] [--set KEY=VALUE ...]

Runs in parallel processes (one per core); prints a Markdown table and writes JSON lines.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
from concurrent.futures import ProcessPoolExecutor

from voxshape.lab.experiment.inprocess import RunSpec, run
from voxshape.runtime.settings import add_settings_argument
from voxshape.services.learner.config import LearnerConfig


def one(job: tuple[str, int, bool, bool, int, tuple[str, ...]]) -> dict:
    task, seed, goal, blend, max_episodes, settings = job
    flags = (f"goal_features={json.dumps(goal)}", f"blend={json.dumps(blend)}")
    r = run(RunSpec(task, "rl", seed, max_episodes, learner=(*settings, *flags)))
    return {
        "task": task,
        "seed": seed,
        "goal_features": goal,
        "blend": blend,
        "converged": r.converged,
        "episodes": r.episodes,
        "learning_min": round(r.learning_time_s / 60, 1),
        "states": r.states,
        "settings": settings,
    }


def median(rows: list[dict], key: str) -> object:
    return statistics.median(r[key] for r in rows) if rows else "-"


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--max-episodes", type=int, default=150)
    parser.add_argument("--goal-features", default="on,off", help="on, off or on,off")
    add_settings_argument(parser, LearnerConfig, "alpha=0.1")
    parser.add_argument("--tasks", default="1,2,3,4")
    parser.add_argument("--blend", action="store_true")
    parser.add_argument("--out", default="plain_rl.jsonl")
    args = parser.parse_args()
    goals = [g == "on" for g in args.goal_features.split(",")]
    jobs = [
        (t, s, g, args.blend, args.max_episodes, tuple(args.set))
        for g in goals
        for t in args.tasks.split(",")
        for s in range(args.seeds)
    ]
    rows = []
    with ProcessPoolExecutor(max_workers=os.cpu_count()) as pool, open(args.out, "w") as out:
        for row in pool.map(one, jobs):
            rows.append(row)
            out.write(json.dumps(row) + "\n")
            out.flush()
    print(
        "| goal features | task | converged | episodes (median, converged runs) | "
        "learning time min (median) | states (median) |"
    )
    print("|---|---|---|---|---|---|")
    for goal in goals:
        for task in args.tasks.split(","):
            runs = [r for r in rows if r["task"] == task and r["goal_features"] == goal]
            done = [r for r in runs if r["converged"]]
            print(
                f"| {'on' if goal else 'off'} | {task} | {len(done)}/{len(runs)} | "
                f"{median(done, 'episodes')} | {median(done, 'learning_min')} | "
                f"{statistics.median(r['states'] for r in runs)} |"
            )


if __name__ == "__main__":
    main()

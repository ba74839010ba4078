"""What initial traces change: the simulated teacher (voxshape/services/simteacher/) dictates a few
episodes along the map's shortest path (commands only, as a person would), then SARSA(lambda)
trains with those traces replayed (before learning and every `replay_every` episodes) and
without them.

    .venv/bin/python benchmarks/initial_traces.py --task 2 --traces 3 --seeds 3
"""

from __future__ import annotations

import argparse

from voxshape.lab.experiment.inprocess import RunSpec, initial_traces, run


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--task", default="2")
    parser.add_argument("--traces", type=int, default=3)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--max-episodes", type=int, default=300)
    args = parser.parse_args()
    print("| traces | seed | converged | episodes | goals reached | states |")
    print("|---|---|---|---|---|---|")
    for traces in (args.traces, 0):
        for seed in range(args.seeds):
            spec = RunSpec(args.task, "rl", seed, args.max_episodes, traces=traces)
            if traces and (dictation := initial_traces(spec)):
                episodes = dictation.book.episodes
                shown = [f"{e[-1][0].outcome} in {len(e) - 1} steps" for e in episodes]
                print(f"<!-- seed {seed}: dictated {', '.join(shown)} -->")
            r = run(spec)
            print(
                f"| {traces} | {seed} | {r.converged} | {r.episodes} | "
                f"{r.outcomes.count('goal')} | {r.states} |",
                flush=True,
            )


if __name__ == "__main__":
    main()

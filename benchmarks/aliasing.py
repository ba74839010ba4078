"""How often a state stands for places that need different actions (perceptual aliasing).

Along the teacher's dictated traces (the shortest path, as `voxshape experiment` dictates
it), a step is aliased when its state (its key: near bits, goal bearing, distance and
sector) is also the state of a step at least `--apart` metres further along the way where
the teacher commanded another action: one table row giving two answers.

    .venv/bin/python benchmarks/aliasing.py --tasks 1,2,3,4,docs/results/other-maps/office.toml
"""

from __future__ import annotations

import argparse
import itertools
import math

import numpy as np

from voxshape.lab.experiment.dictation import dictate
from voxshape.services.learner.config import LearnerConfig
from voxshape.services.learner.states import StateSpace
from voxshape.world.maps import load_map

TRACES, SEED = 3, 10_000  # as the experiments dictate them (inprocess.initial_traces)


def aliasing(task: str, apart: float) -> tuple[float, int]:
    """(share of the traces' steps aliased, steps)."""
    book = dictate(load_map(task), TRACES, seed=SEED).book
    space = StateSpace(LearnerConfig())
    aliased, steps = 0, 0
    for episode in book.episodes:
        taken = [(p, d) for p, d in episode if d is not None]
        poses = [(p.x, p.y) for p, _ in taken]
        actions = [d.discrete for _, d in taken]
        states = [space.classify(p)[0] for p, _ in taken]
        along = np.concatenate(
            [[0.0], np.cumsum([math.dist(a, b) for a, b in itertools.pairwise(poses)])]
        )
        for i, state in enumerate(states):
            steps += 1
            aliased += any(
                states[j] == state and actions[j] != actions[i]
                for j in range(len(states))
                if abs(along[j] - along[i]) >= apart
            )
    return aliased / max(1, steps), steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", default="1,2,3,4")
    parser.add_argument("--apart", type=float, default=2.0, help="metres along the way")
    args = parser.parse_args()
    print("| map | steps | aliased |")
    print("|---|---|---|")
    for task in args.tasks.split(","):
        share, steps = aliasing(task, args.apart)
        print(f"| {task.rsplit('/', 1)[-1]} | {steps} | {share:.2f} |", flush=True)


if __name__ == "__main__":
    main()

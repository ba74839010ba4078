"""How often a state stands for places that need different actions (perceptual aliasing).

Along the teacher's dictated traces (the shortest path, as `voxshape experiment` dictates
it), a step is aliased when its state is also the state of a step at least `--apart` metres
further along the way where the teacher commanded another action. For the key of the
"keys" representation (near bits, goal bearing, distance and sector) that is one table row
giving two answers; for "tiles" the share counts steps whose features (all of them) are
shared that way, and the mean share of features two such steps have in common.

    .venv/bin/python benchmarks/aliasing.py --tasks 1,2,3,4,docs/results/other-maps/office.toml
"""

from __future__ import annotations

import argparse
import itertools
import math

import numpy as np

from voxshape.lab.experiment.dictation import dictate
from voxshape.services.learner.config import LearnerConfig
from voxshape.services.learner.features import representation
from voxshape.world.maps import load_map

TRACES, SEED = 3, 10_000  # as the experiments dictate them (inprocess.initial_traces)


def aliasing(task: str, representation_name: str, apart: float) -> tuple[float, float, int]:
    """(share of the traces' steps aliased, mean share of features such pairs share,
    steps)."""
    book = dictate(load_map(task), TRACES, seed=SEED).book
    features = representation(LearnerConfig(representation=representation_name))
    aliased, shared, steps = 0, [], 0
    for episode in book.episodes:
        poses = [(p.x, p.y) for p, d in episode if d is not None]
        actions = [d.discrete for _, d in episode if d is not None]
        states = [set(features.encode(p)[0].q.tolist()) for p, d in episode if d is not None]
        steps_taken = [math.dist(a, b) for a, b in itertools.pairwise(poses)]
        along = np.concatenate([[0.0], np.cumsum(steps_taken)])
        for i, state in enumerate(states):
            steps += 1
            overlaps = [
                len(state & states[j]) / len(state)
                for j in range(len(states))
                if abs(along[j] - along[i]) >= apart and actions[j] != actions[i]
            ]
            if overlaps and max(overlaps) == 1.0:
                aliased += 1
            shared.append(max(overlaps, default=0.0))
    return aliased / max(1, steps), float(np.mean(shared)), steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", default="1,2,3,4")
    parser.add_argument("--apart", type=float, default=2.0, help="metres along the way")
    args = parser.parse_args()
    print("| map | steps | keys: aliased | tiles: aliased | tiles: features shared |")
    print("|---|---|---|---|---|")
    for task in args.tasks.split(","):
        keys, _, steps = aliasing(task, "keys", args.apart)
        tiles, shared, _ = aliasing(task, "tiles", args.apart)
        name = task.rsplit("/", 1)[-1]
        print(f"| {name} | {steps} | {keys:.2f} | {tiles:.2f} | {shared:.2f} |", flush=True)


if __name__ == "__main__":
    main()

"""What Ray adds to an experiment's wall time: the same small paper experiment (every task and
setting, `--seeds` seeds, the paper's episode limit) in the local process pool and as Ray tasks
on a Ray cluster of one node on this machine's loopback with as many CPUs as the pool has
workers, `--rounds` times in one sitting, each first in turn; whether both gave the same runs; Ray's
overhead per run and as a share of the local pool's wall time. The cluster's start is timed
apart (a real cluster is started once for many experiments).

    .venv/bin/python benchmarks/cluster.py [--seeds 2] [--workers 2] [--rounds 2]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

# A driver of the loopback cluster must resolve 127.0.0.1 as itself (LocalCluster.driver_env).
os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"

from voxshape.lab.experiment.cluster import LocalCluster
from voxshape.lab.experiment.inprocess import SETTINGS, RunSpec
from voxshape.lab.experiment.published import TASKS
from voxshape.lab.experiment.runner import run_all


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--workers", type=int, default=2, help="pool processes, cluster CPUs")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--max-episodes", type=int, default=150)
    args = parser.parse_args()
    specs = [RunSpec(task, setting, seed, args.max_episodes) for task in TASKS
             for setting in SETTINGS for seed in range(args.seeds)]  # fmt: skip
    began = time.perf_counter()
    with LocalCluster(workers=0, cpus=args.workers) as cluster:
        start = time.perf_counter() - began
        walls: dict[str, list[float]] = {"local": [], "ray": []}
        runs: dict[str, list] = {}
        ways = [("local", None), ("ray", cluster.address)]
        for round_ in range(args.rounds):  # each first in turn: the machine's load drifts
            for name, address in ways if round_ % 2 == 0 else ways[::-1]:
                began = time.perf_counter()
                done = run_all(specs, args.workers, progress=False, cluster=address)
                walls[name].append(time.perf_counter() - began)
                runs[name] = [r.to_json() for r in done]
    local, ray = statistics.fmean(walls["local"]), statistics.fmean(walls["ray"])
    print(f"paper experiment, {len(specs)} runs ({args.seeds} seed(s), {args.max_episodes} "
          f"episodes at most), {args.workers} processes / CPUs, {args.rounds} rounds")  # fmt: skip
    print(f"Ray cluster start (one node, loopback): {start:.1f} s, not counted below")
    print("| round | local pool | Ray tasks | Ray / local |")
    print("|---|---|---|---|")
    for i, (a, b) in enumerate(zip(walls["local"], walls["ray"], strict=True), 1):
        print(f"| {i} | {a:.1f} s | {b:.1f} s | {b / a:.3f} |")
    print(f"| mean | {local:.1f} s | {ray:.1f} s | {ray / local:.3f} |")
    ratios = [b / a for a, b in zip(walls["local"], walls["ray"], strict=True)]
    print(f"median ratio of a round: {statistics.median(ratios):.3f}")
    print(f"Ray's overhead: {(ray - local) / len(specs) * 1000:+.0f} ms a run, "
          f"{(ray - local) / local:+.1%} of the local pool's wall time")  # fmt: skip
    print(f"same runs: {'yes' if runs['local'] == runs['ray'] else 'NO'}")


if __name__ == "__main__":
    main()

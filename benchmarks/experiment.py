"""How fast the in-process run is, against its reference path.

Two figures, each measured for the fast path and the reference path (full numpy scans, a
PyBullet contact query at every sub-step: `run(spec, reference=True)`) in the same sitting,
so their ratio holds on a noisy machine:

- robot steps per second in one process, and each core's share of that time (simulator,
  learner, arbiter, simulated teacher; the rest is the run's own loop and messages), over
  the runs of one task;
- the wall time of a small paper experiment (every task and setting, `--seeds` seeds) in
  `--workers` processes, and whether both paths gave the same runs.

    .venv/bin/python benchmarks/experiment.py [--seeds 1] [--workers 2] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from voxshape.lab.experiment.inprocess import SETTINGS, RunSpec, run
from voxshape.lab.experiment.published import TASKS
from voxshape.lab.experiment.runner import run_all
from voxshape.services.arbiter.arbiter import Arbiter
from voxshape.services.learner.sarsa import Learner
from voxshape.services.learner.words import WordCredit
from voxshape.services.sim.task import Simulation
from voxshape.services.simteacher.teacher import SimulatedTeacher

CORES = {  # the methods the run calls of each core (none calls another's)
    "simulator": ((Simulation, "step"), (Simulation, "reset")),
    "learner": (
        (Learner, "step"),
        (Learner, "command"),
        (WordCredit, "judged"),
        (WordCredit, "commanded"),
    ),
    "arbiter": ((Arbiter, "on_observation"), (Arbiter, "on_utterance")),
    "teacher": ((SimulatedTeacher, "watch"),),
}


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=1, help="seeds of the timed experiment")
    parser.add_argument("--workers", type=int, default=2, help="processes")
    parser.add_argument("--share-task", default="1", help="the task whose runs give the shares")
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    return parser


@contextmanager
def timed_cores() -> Iterator[dict[str, float]]:
    """Seconds spent in each core's methods while the block runs (in this process)."""
    spent = dict.fromkeys(CORES, 0.0)
    originals = []
    for core, methods in CORES.items():
        for cls, name in methods:
            original = getattr(cls, name)

            def timed(*args: object, _f=original, _core=core, **kwargs: object) -> object:  # noqa: ANN001
                began = time.perf_counter()
                try:
                    return _f(*args, **kwargs)
                finally:
                    spent[_core] += time.perf_counter() - began

            originals.append((cls, name, original))
            setattr(cls, name, timed)
    try:
        yield spent
    finally:
        for cls, name, original in originals:
            setattr(cls, name, original)


def steps_per_second(specs: list[RunSpec], reference: bool) -> dict:
    """Robot steps per second of the runs, one after another in this process, with each
    core's share of the time."""
    steps, began = 0.0, time.perf_counter()
    with timed_cores() as spent:
        for spec in specs:
            steps += round(sum(run(spec, reference).durations_s) * 10)
    seconds = time.perf_counter() - began
    shares = {core: round(s / seconds, 4) for core, s in spent.items()}
    shares["rest"] = round(1 - sum(shares.values()), 4)
    return {
        "steps": int(steps),
        "seconds": round(seconds, 2),
        "steps_per_s": round(steps / seconds),
        "shares": shares,
    }


def main() -> int:
    args = _parser().parse_args()
    share_specs = [RunSpec(args.share_task, setting, 0) for setting in SETTINGS]
    specs = [
        RunSpec(task, setting, seed)
        for task in TASKS
        for setting in SETTINGS
        for seed in range(args.seeds)
    ]
    result: dict = {"what": "experiment"}
    for name, reference in (("reference", True), ("fast", False)):
        result[name] = steps_per_second(share_specs, reference)
    walls, runs = {}, {}
    for name, reference in (("reference", True), ("fast", False)):
        began = time.perf_counter()
        runs[name] = [
            r.to_json() for r in run_all(specs, args.workers, progress=False, reference=reference)
        ]
        walls[name] = time.perf_counter() - began
    result["experiment"] = {
        "runs": len(specs),
        "workers": args.workers,
        "reference_wall_s": round(walls["reference"], 1),
        "fast_wall_s": round(walls["fast"], 1),
        "same_runs": runs["reference"] == runs["fast"],
    }
    result["steps_per_s_ratio"] = round(
        result["fast"]["steps_per_s"] / result["reference"]["steps_per_s"], 2
    )
    result["wall_time_ratio"] = round(walls["reference"] / walls["fast"], 2)
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"in-process run, task {args.share_task}, every setting, seed 0, one process:")
    print(f"{'':<10} {'steps/s':>8} " + " ".join(f"{c:>9}" for c in [*CORES, "rest"]))
    for name in ("reference", "fast"):
        r = result[name]
        print(
            f"{name:<10} {r['steps_per_s']:>8} "
            + " ".join(f"{v:>9.0%}" for v in r["shares"].values())
        )
    e = result["experiment"]
    print(
        f"paper experiment, {e['runs']} runs ({args.seeds} seed(s)), {e['workers']} workers: "
        f"reference {e['reference_wall_s']} s, fast {e['fast_wall_s']} s, "
        f"same runs: {'yes' if e['same_runs'] else 'NO'}"
    )
    ratios = result["steps_per_s_ratio"], result["wall_time_ratio"]
    print(f"fast / reference: {ratios[0]}x steps/s, {ratios[1]}x wall time")
    return 0 if e["same_runs"] else 1


if __name__ == "__main__":
    sys.exit(main())

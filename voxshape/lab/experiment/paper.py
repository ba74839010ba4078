"""`voxshape experiment paper`: the paper's Section 4 again, with many more runs.

4 tasks x 4 settings x N seeds of voxshape/lab/experiment/inprocess.py, in parallel processes (one
per core), or as Ray tasks on a cluster (`--cluster`: cluster.py). Writes to the output
directory:

- results.json: every run, and per task and setting the means (episodes, learning time,
  interventions, share converged) with 95% confidence intervals; the speedup of each setting
  (mean RL learning time over the tasks / the setting's, the paper's own ratio) with a 95%
  bootstrap interval, and the mean interventions of each feedback setting;
- report.md: Tables 2 and 3 in the paper's layout, ours beside the paper's numbers; averages and
  speedups beside the paper's over the same built-in tasks (map files have no paper figure);
- figure2.png: episode duration against episode, one line per setting (the paper's Figure 2);
- runs.jsonl: each run as it finishes, with the RunSpec it ran (setting, teacher, learner);
  `--resume DIR` keeps those runs and runs the others.

`voxshape experiment pool DIR DIR...` writes the same three files for the runs of several
outputs taken as one experiment (seeds 0-9 and the held-out 10-19: 20 seeds).

A run that does not converge within max_episodes is censored: it counts with its time so far
(a lower bound) and is flagged; a setting's cell with censored runs is marked.

Its parts: runner.py runs the specs (runs.jsonl, --resume), summary.py and intervals.py make
results.json, paper_report.py report.md beside the paper's figures (published.py), figure2.py
the figure; legend.py names and draws each setting in all of them.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Callable
from pathlib import Path

from voxshape.lab.experiment.figure2 import figure2
from voxshape.lab.experiment.inprocess import RunResult, RunSpec
from voxshape.lab.experiment.paper_report import paper_markdown
from voxshape.lab.experiment.results import summarize_runs
from voxshape.lab.experiment.runner import run_all, spec_key, start_log
from voxshape.services.simteacher.teacher import PROFILES


def experiment(
    out: Path,
    tasks: list[str],
    settings: list[str],
    seeds: range,
    max_episodes: int,
    command: str,
    workers: int | None = None,
    progress: bool = True,
    clock: Callable[[], float] | None = None,
    learner: tuple[str, ...] = (),
    teacher: tuple[str, ...] = (),
    profile: str = "person",
    cluster: str | None = None,
    resume: bool = False,
) -> dict:
    """Runs the experiment and writes results.json, report.md and figure2.png to `out`;
    `learner` changes the learner's configuration (`--set KEY=VALUE`) in every run, and
    `teacher` the simulated teacher's `profile` (`--teacher KEY=VALUE`); `cluster`: on that
    Ray cluster (run_all); `resume`: the runs already in `out`'s runs.jsonl are kept."""
    import time

    clock = clock or time.monotonic
    began = clock()
    specs = [
        RunSpec(
            task,
            setting,
            seed,
            max_episodes,
            profile=PROFILES[profile],
            learner=learner,
            teacher=teacher,
        )
        for task in tasks
        for setting in settings
        for seed in seeds
    ]
    out.mkdir(parents=True, exist_ok=True)
    done = start_log(out / "runs.jsonl", specs, resume)
    results = run_all(specs, workers, progress, out / "runs.jsonl", cluster=cluster, done=done)
    wall = clock() - began
    summary = summarize_runs(results, len(seeds))
    summary["first_seed"] = seeds.start
    summary.update(command=command, wall_time_s=round(wall, 1), max_episodes=max_episodes)
    summary.update(learner_settings=list(learner), teacher_settings=list(teacher))
    summary["teacher_profile"] = profile
    if done:
        summary["resumed_runs"] = sum(spec_key(spec) in done for spec in specs)
    _write(out, summary, results)
    return summary


def _write(out: Path, summary: dict, results: list[RunResult]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(summary, indent=1))
    (out / "report.md").write_text(
        paper_markdown(summary, summary["command"], summary["wall_time_s"])
    )
    figure2(results, out / "figure2.png")


class PoolError(ValueError):
    """Results that cannot be pooled; the message names the directory and why."""


POOLED_ALIKE = ("max_episodes", "learner_settings", "teacher_settings", "teacher_profile")


def pool(dirs: list[Path], out: Path, command: str) -> dict:
    """The runs of several `experiment paper` outputs (their results.json) as one experiment:
    writes results.json, report.md and figure2.png to `out`. Refuses outputs run with another
    episode limit or other learner or teacher settings, and a run found in two of them."""
    loaded, runs = [], []
    for d in dirs:
        path = d / "results.json"
        try:
            results = json.loads(path.read_text())
            runs += [RunResult.from_json(r) for r in results["runs"]]
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise PoolError(
                f"{path}: not the results.json of `voxshape experiment paper` ({e})"
            ) from None
        loaded.append(results)
    for d, results in zip(dirs[1:], loaded[1:], strict=True):
        for key in POOLED_ALIKE:
            if results.get(key) != loaded[0].get(key):
                raise PoolError(
                    f"{d}: its {key} {results.get(key)!r} differ from {dirs[0]}'s "
                    f"{loaded[0].get(key)!r}: only runs of the same experiment pool"
                )
    twice = [k for k, n in Counter((r.task, r.setting, r.seed) for r in runs).items() if n > 1]
    if twice:
        task, setting, seed = twice[0]
        raise PoolError(
            f"task {task} {setting} seed {seed} is in more than one of {', '.join(map(str, dirs))}"
            ": pool experiments of other seeds (run them with --first-seed)"
        )
    summary = summarize_runs(runs, len({r.seed for r in runs}))
    summary["first_seed"] = min(r.seed for r in runs)
    summary.update({key: loaded[0].get(key) for key in POOLED_ALIKE})
    summary.update(
        command=command,
        wall_time_s=round(sum(results.get("wall_time_s", 0.0) for results in loaded), 1),
        pooled=[str(d) for d in dirs],
    )
    _write(out, summary, runs)
    return summary

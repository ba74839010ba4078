"""results.json's content: per task and setting the means of the runs with their 95%
intervals and the share converged; per setting the speedup over RL (with its bootstrap
interval and whether it is a bound), the words said, the robot seconds each word saved, the
time lost to timeouts and to bump bouts, and the robot's questions.

A setting's time is the robot's time the person's teaching took: the dictation of its initial
traces (`dictation_s`), then learning until convergence (`learning_time_s`)."""

from __future__ import annotations

import functools
import statistics

from voxshape.lab.experiment.inprocess import SETTINGS, RunResult
from voxshape.lab.experiment.intervals import mean_ci, speedup_interval
from voxshape.lab.experiment.published import TASKS, paper_average
from voxshape.world.maps import MapError, load_map

CELL_FIGURES = ("episodes", "learning_time_s", "dictation_s", "robot_time_s", "interventions",
                "dictation_words", "words")  # fmt: skip


def summarize(results: list[RunResult], seeds: int) -> dict:
    """results.json's content: the runs, the means per task and setting, speedups."""
    tasks = sorted({r.task for r in results})
    settings = [s for s in SETTINGS if any(r.setting == s for r in results)]
    cells = _cells(results, tasks, settings)
    of = {s: [r for r in results if r.setting == s] for s in settings}

    def over_tasks(setting: str, key: str) -> float:
        return statistics.fmean(cells[t][setting][key] for t in tasks if setting in cells[t])

    means = {s: over_tasks(s, "robot_time_s") for s in settings}
    speedup = {s: means["rl"] / means[s] for s in settings if s != "rl" and "rl" in means}
    taught = [s for s in settings if SETTINGS[s].feedback or SETTINGS[s].traces]
    built_in = [t for t in tasks if t in TASKS]
    return {
        "seeds": seeds,
        "tasks": cells,
        "paper": {"tasks": built_in, **paper_average(built_in)},  # over the same tasks
        "mean_robot_time_s": means,
        "mean_learning_time_s": {s: over_tasks(s, "learning_time_s") for s in settings},
        "mean_dictation_s": {s: over_tasks(s, "dictation_s") for s in settings},
        "speedup": speedup,
        "speedup_ci95": {s: speedup_interval(of["rl"], of[s], tasks) for s in speedup},
        "speedup_bound": {s: speedup_bound(cells, tasks, s) for s in speedup},
        "interventions": {s: over_tasks(s, "interventions") for s in taught},
        "dictation_words": {s: over_tasks(s, "dictation_words") for s in taught},
        "words": {s: over_tasks(s, "words") for s in taught},
        "seconds_saved_per_word": {
            s: (means["rl"] - means[s]) / w
            for s in taught
            if "rl" in means and (w := over_tasks(s, "words"))
        },
        "timeout_share": {s: timeout_share(of[s]) for s in settings},
        "bump_bout_share": {s: bump_bout_share(of[s]) for s in settings},
        "changed_by_person": {
            s: statistics.fmean(r.changed_by_person for r in of[s]) for s in taught
        },
        "changed_toward_way": {s: toward_way(of[s]) for s in taught},
        "questions": {
            s: {
                key: statistics.fmean(r.counters.get(counter, 0) for r in of[s])
                for key, counter in (
                    ("asked", "learner.questions"),
                    ("answered", "teacher.answers"),
                )
            }
            for s in settings
            if SETTINGS[s].ask
        },
        "runs": [r.to_json() for r in results],
    }


def toward_way(runs: list[RunResult]) -> float | None:
    """The mean over the runs (that had any) of the share of the decisions the person changed
    that led along the true way; None if the person changed none."""
    shares = [r.changed_toward_way for r in runs if r.changed_toward_way is not None]
    return statistics.fmean(shares) if shares else None


def speedup_bound(cells: dict, tasks: list[str], setting: str) -> str:
    """What a speedup over RL is when runs were censored (counted with their time so far,
    so their means are lower bounds): "exact" if none were; "lower" if only RL's were (RL's
    true mean is larger); "upper" if only the setting's were; "none" if both were."""
    rl = any(cells[t]["rl"]["converged_fraction"] < 1 for t in tasks if "rl" in cells[t])
    ours = any(cells[t][setting]["converged_fraction"] < 1 for t in tasks if setting in cells[t])
    return {(False, False): "exact", (True, False): "lower", (False, True): "upper"}.get(
        (rl, ours), "none"
    )


def _cells(results: list[RunResult], tasks: list[str], settings: list[str]) -> dict:
    """Per task and setting: the mean and 95% interval of each figure, and the share that
    converged."""
    cells: dict[str, dict[str, dict]] = {}
    for task in tasks:
        cells[task] = {}
        for setting in settings:
            runs = [r for r in results if r.task == task and r.setting == setting]
            if not runs:
                continue
            cell = {"runs": len(runs)}
            for key in CELL_FIGURES:
                cell[key], cell[f"{key}_ci95"] = mean_ci(getattr(r, key) for r in runs)
            cell["converged_fraction"] = sum(r.converged for r in runs) / len(runs)
            cells[task][setting] = cell
    return cells


@functools.cache
def _timeout_of(task: str) -> float:
    """The episodes' timeout of a task run before results recorded it (0: its map is gone)."""
    try:
        return load_map(task).timeout
    except MapError:
        return 0.0


def timeout_share(runs: list[RunResult]) -> float:
    """The share of the robot's time until convergence spent in episodes that timed out."""
    total = lost = 0.0
    for r in runs:
        timeout = r.timeout_s or _timeout_of(r.task)
        episodes = r.durations_s[: r.episodes]
        total += sum(episodes)
        lost += sum(d for d in episodes if timeout and d >= timeout - 1e-6)
    return lost / total if total else 0.0


def bump_bout_share(runs: list[RunResult]) -> float:
    """The share of the robot's learning time until convergence spent in bump bouts of 10 s
    or more (experiment/bouts.py)."""
    total = sum(r.learning_time_s for r in runs)
    return sum(r.bump_bout_s for r in runs) / total if total else 0.0

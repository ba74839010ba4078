"""results.json's content: per task and setting the means of the runs with their 95%
intervals and the share converged; per setting the speedup over RL (with its bootstrap
interval), the interventions, the words dictating traces, the time lost to timeouts and the
robot's questions."""

from __future__ import annotations

import functools
import statistics

from services.experiment.inprocess import SETTINGS, RunResult
from services.experiment.intervals import mean_ci, speedup_interval
from services.experiment.published import TASKS, paper_average
from services.world.maps import MapError, load_map


def summarize(results: list[RunResult], seeds: int) -> dict:
    """results.json's content: the runs, the means per task and setting, speedups."""
    tasks = sorted({r.task for r in results})
    settings = [s for s in SETTINGS if any(r.setting == s for r in results)]
    cells = _cells(results, tasks, settings)
    means = {
        s: statistics.fmean(cells[t][s]["learning_time_s"] for t in tasks if s in cells[t])
        for s in settings
    }
    speedup = {s: means["rl"] / means[s] for s in settings if s != "rl" and "rl" in means}
    rl_runs = [r for r in results if r.setting == "rl"]
    speedup_ci95 = {
        s: speedup_interval(rl_runs, [r for r in results if r.setting == s], tasks) for s in speedup
    }
    interventions = {
        s: statistics.fmean(cells[t][s]["interventions"] for t in tasks if s in cells[t])
        for s in settings
        if SETTINGS[s].feedback
    }
    trace_words = {
        s: statistics.fmean(cells[t][s]["trace_words"] for t in tasks if s in cells[t])
        for s in settings
        if SETTINGS[s].feedback
    }
    built_in = [t for t in tasks if t in TASKS]
    return {
        "seeds": seeds,
        "tasks": cells,
        "paper": {"tasks": built_in, **paper_average(built_in)},  # over the same tasks
        "mean_learning_time_s": means,
        "speedup": speedup,
        "speedup_ci95": speedup_ci95,
        "speedup_is_lower_bound": any(
            cells[t]["rl"]["converged_fraction"] < 1 for t in tasks if "rl" in cells[t]
        ),
        "interventions": interventions,
        "trace_words": trace_words,
        "timeout_share": {
            s: timeout_share([r for r in results if r.setting == s]) for s in settings
        },
        "questions": {
            s: {
                key: statistics.fmean(r.counters.get(counter, 0) for r in runs)
                for key, counter in (
                    ("asked", "learner.questions"),
                    ("answered", "teacher.answers"),
                )
            }
            for s in settings
            if SETTINGS[s].ask and (runs := [r for r in results if r.setting == s])
        },
        "runs": [r.to_json() for r in results],
    }


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
            for key in ("episodes", "learning_time_s", "interventions", "trace_words"):
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

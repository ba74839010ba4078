"""`voxshape experiment paper`: the paper's Section 4 again, with many more runs.

4 tasks x 4 settings x N seeds of services/experiment/inprocess.py, in parallel processes (one
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
"""

from __future__ import annotations

import functools
import json
import math
import os
import random
import statistics
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from operator import attrgetter
from pathlib import Path

from tqdm import tqdm

from services.experiment.cluster import failure, on_ray
from services.experiment.inprocess import SETTINGS, RunResult, RunSpec, run
from services.learner.config import LearnerConfig
from services.learner.convergence import Convergence
from services.teacher.simulated.teacher import PROFILES
from services.world.maps import MapError, load_map

TASKS = ("1", "2", "3", "4")
LABELS = {
    "rl": "RL",
    "rl+f": "RL + F",
    "rl+t+f": "RL + T + F",
    "rl+t+f-perfect": "RL + T + F (PF)",
    "rl+f+ask": "RL + F + ask",
    "rl+t+f+ask": "RL + T + F + ask",
}
# The paper's Tables 2 and 3 (3 repeats per cell). Times in minutes.
PAPER_EPISODES = {
    "rl": {"1": 13, "2": 6, "3": 12, "4": 7},
    "rl+f": {"1": 9, "2": 7, "3": 12, "4": 12},
    "rl+t+f": {"1": 6, "2": 7, "3": 7, "4": 11},
}
PAPER_MINUTES = {
    "rl": {"1": 103.93, "2": 66.4, "3": 100.65, "4": 99.1},
    "rl+f": {"1": 19.59, "2": 15.1, "3": 38.2, "4": 23.43},
    "rl+t+f": {"1": 12.85, "2": 13, "3": 18.09, "4": 24.61},
    "rl+t+f-perfect": {"2": 7.6},
}
PAPER_INTERVENTIONS = {
    "rl+f": {"1": 71, "2": 53, "3": 143, "4": 69},
    "rl+t+f": {"1": 23, "2": 34, "3": 40, "4": 72},
    "rl+t+f-perfect": {"2": 39},
}
# The paper's averages over its four tasks, as printed; over fewer tasks, paper_average computes
# them from the per-task tables above.
PAPER_AVERAGE = {
    "episodes": {"rl": 9.5, "rl+f": 10, "rl+t+f": 7.75},
    "minutes": {"rl": 92.54, "rl+f": 24.08, "rl+t+f": 17.13},
    "interventions": {"rl+f": 84, "rl+t+f": 42},
    "speedup": {"rl+f": 3.84, "rl+t+f": 5.4},
}
# Student's t, two-sided 95%, by degrees of freedom (1-30); beyond, the normal's 1.96.
T95 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179,
       2.160, 2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064,
       2.060, 2.056, 2.052, 2.048, 2.045, 2.042)  # fmt: skip


def paper_average(tasks: Iterable[str]) -> dict[str, dict[str, float]]:
    """The paper's averages over `tasks` (map files have none and are left out), from its
    per-task tables: episodes, minutes and interventions per setting, and each setting's
    speedup (the paper's mean RL minutes over those tasks / the setting's). A setting without
    a figure for every one of the tasks has none; over all four tasks, the printed averages."""
    built_in = [t for t in TASKS if t in set(tasks)]
    if built_in == list(TASKS):
        return {key: dict(values) for key, values in PAPER_AVERAGE.items()}
    if not built_in:
        return {key: {} for key in PAPER_AVERAGE}

    def mean(table: dict[str, dict[str, float]]) -> dict[str, float]:
        return {
            setting: statistics.fmean(figures[t] for t in built_in)
            for setting, figures in table.items()
            if all(t in figures for t in built_in)
        }

    minutes = mean(PAPER_MINUTES)
    speedup = {s: minutes["rl"] / m for s, m in minutes.items() if s != "rl" and "rl" in minutes}
    return {
        "episodes": mean(PAPER_EPISODES),
        "minutes": minutes,
        "interventions": mean(PAPER_INTERVENTIONS),
        "speedup": speedup,
    }


def mean_ci(values: Iterable[float]) -> tuple[float, float]:
    """The mean and the half-width of its 95% confidence interval (Student's t; 0 for n=1)."""
    values = list(values)
    mean = statistics.fmean(values)
    if len(values) < 2:
        return mean, 0.0
    t = T95[len(values) - 2] if len(values) - 1 <= len(T95) else 1.96
    return mean, t * statistics.stdev(values) / math.sqrt(len(values))


def task_means(runs: list[RunResult], tasks: list[str]) -> float:
    """The mean over the tasks of the mean learning time of each (the paper's average)."""
    return statistics.fmean(
        statistics.fmean(r.learning_time_s for r in runs if r.task == t) for t in tasks
    )


def speedup_interval(
    rl: list[RunResult], runs: list[RunResult], tasks: list[str], draws: int = 2000
) -> tuple[float, float]:
    """A 95% bootstrap interval of the speedup: both sets of runs resampled within each task
    (seeded, and the runs taken in seed order, so a report is reproducible)."""
    rng = random.Random(0)

    def resampled(sample: list[RunResult]) -> list[RunResult]:
        by_task = [
            sorted((r for r in sample if r.task == t), key=attrgetter("seed")) for t in tasks
        ]
        return [r for group in by_task for r in rng.choices(group, k=len(group))]

    ratios = sorted(
        task_means(resampled(rl), tasks) / task_means(resampled(runs), tasks) for _ in range(draws)
    )
    return ratios[int(0.025 * draws)], ratios[int(0.975 * draws) - 1]


class RunsFailed(RuntimeError):
    """Runs that failed for good (after Ray's retries on a cluster), each named by task,
    setting and seed; the runs that finished are in the log, for `--resume`."""

    def __init__(self, failed: list[tuple[RunSpec, str]], finished: int) -> None:
        self.failed = failed
        named = "; ".join(f"task {s.task} {s.setting} seed {s.seed}: {why}" for s, why in failed)
        super().__init__(f"{len(failed)} run(s) failed, {finished} finished: {named}")


def spec_key(spec: RunSpec | dict) -> str:
    """A run's identity as runs.jsonl keeps it: its RunSpec (task, setting, seed, teacher,
    learner, episode limit), as JSON."""
    return json.dumps(asdict(spec) if isinstance(spec, RunSpec) else spec, sort_keys=True)


class ResumeError(ValueError):
    """An output directory without runs.jsonl, or whose runs are of another experiment."""


def resumed(log: Path, specs: list[RunSpec]) -> dict[str, RunResult]:
    """The runs of `specs` already in `log` (runs.jsonl of an interrupted experiment), by
    spec_key; a run of other arguments there is refused (ResumeError), a last line cut short
    by the interrupt is left out."""
    wanted = {spec_key(spec) for spec in specs}
    done: dict[str, RunResult] = {}
    if not log.exists():
        raise ResumeError(f"{log} not found: nothing to resume there (check --resume)")
    lines = log.read_text().splitlines()
    for number, line in enumerate(lines, 1):
        try:
            result = RunResult(**json.loads(line))
        except (ValueError, TypeError):
            if number == len(lines):
                continue  # written when the experiment was stopped
            raise ResumeError(f"{log}:{number}: not a run of `voxshape experiment`") from None
        key = spec_key(result.spec)
        if key not in wanted:
            raise ResumeError(
                f"{log}:{number}: task {result.task} {result.setting} seed {result.seed} was "
                "run with other arguments (episode limit, --set, --teacher, --tasks or seeds): "
                "resume with the arguments the experiment was started with"
            )
        done[key] = result
    return done


def start_log(log: Path, specs: list[RunSpec], resume: bool) -> dict[str, RunResult]:
    """Readies runs.jsonl for an experiment: emptied, or with `resume` read for the runs
    done (`resumed`) and rewritten with them alone (a line cut short is dropped)."""
    if not resume:
        log.unlink(missing_ok=True)
        return {}
    done = resumed(log, specs)
    log.write_text("".join(json.dumps(r.to_json()) + "\n" for r in done.values()))
    return done


def _locally(
    specs: list[RunSpec], workers: int, reference: bool
) -> Iterator[tuple[int, RunResult | BaseException]]:
    """Each run in a local process pool: (index in `specs`, its result or its error)."""
    with ProcessPoolExecutor(max_workers=workers) as pool:
        futures = {pool.submit(run, spec, reference): i for i, spec in enumerate(specs)}
        for future in as_completed(futures):
            try:
                yield futures[future], future.result()
            except Exception as e:  # the run's own error, or its process lost
                yield futures[future], e


def run_all(
    specs: list[RunSpec],
    workers: int | None = None,
    progress: bool = True,
    log: Path | None = None,
    reference: bool = False,
    cluster: str | None = None,
    done: dict[str, RunResult] | None = None,
) -> list[RunResult]:
    """Every run (in the order of `specs`), in local processes or, with `cluster` (a Ray
    address), as Ray tasks on that cluster, with a progress bar on stderr; with `log`, each
    result is appended to it as a JSON line as soon as it is done (a long experiment cut short
    keeps what it ran); runs in `done` (by spec_key: `resumed`) are not run again;
    `reference`: on the simulator's reference path (`run`). Raises RunsFailed naming the runs
    that failed, once the others are done."""
    done = done or {}
    results: list[RunResult | None] = [done.get(spec_key(spec)) for spec in specs]
    # The longest runs first (plain RL learns 5-8x slower), so none is left alone at the end.
    todo = sorted((i for i, r in enumerate(results) if r is None),
                  key=lambda i: specs[i].setting != "rl")  # fmt: skip
    failed: list[tuple[RunSpec, str]] = []
    if cluster:
        outcomes = on_ray([specs[i] for i in todo], reference, cluster)
    else:
        outcomes = _locally([specs[i] for i in todo], workers or os.cpu_count() or 1, reference)
    with tqdm(total=len(specs), initial=len(specs) - len(todo), unit="run",
              disable=not progress, leave=False) as bar:  # fmt: skip
        for position, outcome in outcomes:
            index = todo[position]
            if isinstance(outcome, BaseException):
                failed.append((specs[index], failure(outcome)))
            else:
                results[index] = outcome
                if log is not None:
                    with log.open("a") as lines:
                        lines.write(json.dumps(outcome.to_json()) + "\n")
            bar.update(1)
    if failed:
        raise RunsFailed(failed, sum(r is not None for r in results))
    return [r for r in results if r is not None]


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


def _cell(summary: dict, task: str, setting: str, key: str, scale: float = 1.0) -> str:
    cell = summary["tasks"].get(task, {}).get(setting)
    if cell is None:
        return "-"
    censored = "≥" if cell["converged_fraction"] < 1 and key != "interventions" else ""
    return f"{censored}{cell[key] / scale:.1f} ± {cell[key + '_ci95'] / scale:.1f}"


def _seed_range(summary: dict) -> str:
    spans: list[list[int]] = []  # runs of consecutive seeds, [first, last]
    for seed in sorted({r["seed"] for r in summary["runs"]}):
        if spans and seed == spans[-1][1] + 1:
            spans[-1][1] = seed
        else:
            spans.append([seed, seed])
    return "seeds " + ", ".join(f"{a}-{b}" if a < b else f"{a}" for a, b in spans)


def task_label(task: str) -> str:
    """T1..T4 for the built-in tasks, a map file by its name (`--tasks 1,my-office.toml`)."""
    return f"T{task}" if task in TASKS else Path(task).name


def _teacher(summary: dict) -> str:
    """Who taught: the simulated teacher's profile and the changes made to it."""
    name = summary.get("teacher_profile", "tireless")  # results from before the profiles
    changes = summary.get("teacher_settings") or []
    changed = f", with {', '.join(changes)}" if changes else ""
    return f"The simulated teacher: {name} ({PROFILES[name].describe()}){changed}."


def _built_in_row(
    summary: dict, built_in: list[str], settings: list[str], key: str, paper: dict
) -> str:
    """The row of the built-in tasks alone, ours beside the paper's (minutes or counts)."""
    scale = 60 if key == "learning_time_s" else 1
    cells = []
    for s in settings:
        ours = _over(summary, built_in, s, key)
        cells.append(f"{'-' if ours is None else f'{ours / scale:.1f}'} | {_figure(paper.get(s))}")
    return f"| Avg of {_labels(built_in)} | " + " | ".join(cells) + " |"


def _paper(table: dict, setting: str, task: str) -> str:
    value = table.get(setting, {}).get(task)
    return "-" if value is None else f"{value:g}"


def _figure(value: float | None) -> str:
    """A paper figure: as printed (92.54, 84), or computed to two decimals."""
    return "-" if value is None else f"{round(value, 2):g}"


def _over(summary: dict, tasks: list[str], setting: str, key: str) -> float | None:
    """Our mean of a cell's `key` over `tasks` (None if a task lacks the setting)."""
    cells = [summary["tasks"][t].get(setting) for t in tasks]
    if not tasks or any(c is None for c in cells):
        return None
    return statistics.fmean(c[key] for c in cells)


def _labels(tasks: list[str]) -> str:
    return ", ".join(task_label(t) for t in tasks)


def paper_note(tasks: list[str], built_in: list[str]) -> str:
    """Which of the paper's figures the averages and speedups are compared with."""
    maps = [t for t in tasks if t not in TASKS]
    if not built_in:
        return f"Map files ({_labels(maps)}) have no paper figures: nothing to compare with."
    if built_in == list(TASKS) and not maps:
        return ""  # the paper's own four-task averages, as printed
    note = (
        f"The paper's figures: its averages and speedups over the same built-in tasks "
        f"({_labels(built_in)}), from its per-task tables, not its four-task averages."
    )
    if maps:
        note += (
            f" Map files ({_labels(maps)}) have no paper figure: the averages of all tasks "
            "are not compared, those of the built-in tasks alone are."
        )
    return note


@dataclass(frozen=True)
class _Scope:
    """The tasks a report covers, and the paper's figures over the same built-in tasks."""

    tasks: list[str]
    built_in: list[str]  # the built-in tasks among them: map files have no paper figures
    paper: dict[str, dict[str, float]]  # paper_average over built_in

    @classmethod
    def of(cls, tasks: list[str]) -> _Scope:
        built_in = [t for t in tasks if t in TASKS]
        return cls(tasks, built_in, paper_average(built_in))

    @property
    def mixed(self) -> bool:
        """Built-in tasks and map files: the paper's figures go on rows of the built-in alone."""
        return bool(self.built_in) and len(self.built_in) < len(self.tasks)

    @property
    def average_label(self) -> str:
        return "Avg" if self.tasks == list(TASKS) else f"Avg of {_labels(self.tasks)}"


def report(summary: dict, command: str, wall_seconds: float) -> str:
    """The Markdown report: Tables 2 and 3 in the paper's layout, ours beside the paper's."""
    tasks = list(summary["tasks"])
    settings = [s for s in SETTINGS if any(s in summary["tasks"][t] for t in tasks)]
    feedback = [s for s in settings if SETTINGS[s].feedback]
    scope = _Scope.of(tasks)
    lines = _introduction(summary, command, wall_seconds)
    lines += _table2(summary, scope, settings)
    lines += _speedups(summary, scope)
    lines += _table3(summary, scope, feedback)
    lines += _teacher_words(summary, feedback)
    lines += _asking(summary, settings)
    lines += _noisy_against_perfect(summary)
    lines += _FIGURE2_SECTION
    return "\n".join(lines)


def _introduction(summary: dict, command: str, wall_seconds: float) -> list[str]:
    """The title, what was run, and how to read a cell, naming the censored runs (a few)."""
    runs = summary["runs"]
    censored = [r for r in runs if not r["converged"]]
    named = (
        ": " + ", ".join(f"task {r['task']} {r['setting']} seed {r['seed']}" for r in censored)
        if 0 < len(censored) <= 12
        else ""
    )
    return [
        "# Dynamic reward shaping: the paper's experiments again",
        "",
        f"`{command}`: {len(runs)} runs ({summary['seeds']} seeds per task and setting, "
        f"{_seed_range(summary)}), "
        f"{wall_seconds / 60:.1f} min of wall time on {os.cpu_count()} cores. " + _teacher(summary),
        "",
        "Ours: mean ± half-width of the 95% confidence interval (Student's t) over seeds. "
        "Learning time is the robot's simulated time until convergence ("
        + Convergence(LearnerConfig()).rule()
        + ", the shortest time of each task's map). **Censored runs**: a run that did not "
        "converge within the episode limit counts with its time so far, so its cell's mean "
        f"is a lower bound, marked ≥ ({len(censored)} of {len(runs)} runs censored{named}).",
        "",
    ]


def _table2(summary: dict, scope: _Scope, settings: list[str]) -> list[str]:
    """Table 2: episodes, then learning time in minutes with its averages over the tasks."""
    lines = ["## Table 2: episodes (left) and learning time in minutes (right)", ""]
    lines += ["Episodes:", "", *_head(settings)]
    lines += _task_rows(summary, scope.tasks, settings, "episodes", PAPER_EPISODES)
    lines += ["", "Learning time (minutes):", "", *_head(settings)]
    lines += _task_rows(summary, scope.tasks, settings, "learning_time_s", PAPER_MINUTES, 60)
    minutes = {s: summary["mean_learning_time_s"][s] / 60 for s in settings}
    lines += _average_rows(summary, scope, settings, "learning_time_s", minutes, "minutes")
    note = paper_note(scope.tasks, scope.built_in)
    return lines + (["", note] if note else [])


def _speedups(summary: dict, scope: _Scope) -> list[str]:
    """Each setting's speedup over RL with its bootstrap interval, beside the paper's."""
    bound = "≥ " if summary["speedup_is_lower_bound"] else ""
    lines = ["", "Speedup over RL (mean RL learning time over the tasks / the setting's):", ""]
    lines += ["| setting | ours | 95% interval | paper |", "|---|---|---|---|"]
    for setting, value in summary["speedup"].items():
        theirs = "-" if scope.mixed else _figure(scope.paper["speedup"].get(setting))
        low, high = summary["speedup_ci95"][setting]
        lines.append(
            f"| {LABELS[setting]} | {bound}{value:.2f} | {low:.2f}-{high:.2f} | {theirs} |"
        )
    if scope.mixed and summary["speedup"]:
        lines += _built_in_speedups(summary, scope, bound)
    if bound:
        lines += [
            "",
            "RL did not always converge within the episode limit: its mean is a lower bound, "
            "so the speedups are lower bounds too.",
        ]
    return lines


def _built_in_speedups(summary: dict, scope: _Scope, bound: str) -> list[str]:
    """The speedups over the built-in tasks alone, against the paper's over them."""
    lines = [
        "",
        f"On the built-in tasks alone ({_labels(scope.built_in)}), against the paper's "
        "speedups over them:",
        "",
        "| setting | ours | paper |",
        "|---|---|---|",
    ]
    rl = _over(summary, scope.built_in, "rl", "learning_time_s")
    for setting in summary["speedup"]:
        ours = _over(summary, scope.built_in, setting, "learning_time_s")
        value = "-" if rl is None or not ours else f"{bound}{rl / ours:.2f}"
        lines.append(
            f"| {LABELS[setting]} | {value} | {_figure(scope.paper['speedup'].get(setting))} |"
        )
    return lines


def _table3(summary: dict, scope: _Scope, feedback: list[str]) -> list[str]:
    """Table 3: the interventions of each feedback setting, with their averages."""
    lines = ["", "## Table 3: interventions (understood utterances until convergence)", ""]
    lines += _head(feedback)
    lines += _task_rows(summary, scope.tasks, feedback, "interventions", PAPER_INTERVENTIONS)
    interventions = summary["interventions"]
    return lines + _average_rows(
        summary, scope, feedback, "interventions", interventions, "interventions"
    )


def _head(settings: list[str]) -> list[str]:
    """A table's header: per setting, ours and the paper's."""
    return [
        "| task | " + " | ".join(f"{LABELS[s]} ours | paper" for s in settings) + " |",
        "|---|" + "---|---|" * len(settings),
    ]


def _task_rows(
    summary: dict,
    tasks: list[str],
    settings: list[str],
    key: str,
    table: dict[str, dict[str, float]],
    scale: float = 1.0,
) -> list[str]:
    """A row per task: our cell of `key` beside the paper's figure in `table`, per setting."""
    rows = []
    for task in tasks:
        cells = [f"{_cell(summary, task, s, key, scale)} | {_paper(table, s, task)}"
                 for s in settings]  # fmt: skip
        rows.append(f"| {task_label(task)} | " + " | ".join(cells) + " |")
    return rows


def _average_rows(
    summary: dict,
    scope: _Scope,
    settings: list[str],
    key: str,
    ours: dict[str, float],
    figure: str,
) -> list[str]:
    """Our averages over all the tasks beside the paper's `figure` (none with map files among
    them), and with map files a row of the built-in tasks alone."""
    theirs = scope.paper[figure]
    cells = [
        f"{ours[s]:.1f} | " + ("-" if scope.mixed else _figure(theirs.get(s))) for s in settings
    ]
    lines = [f"| {scope.average_label} | " + " | ".join(cells) + " |"]
    if scope.mixed:
        lines.append(_built_in_row(summary, scope.built_in, settings, key, theirs))
    return lines


def _teacher_words(summary: dict, feedback: list[str]) -> list[str]:
    """Every word a teacher says per run: while the robot learns, and dictating the traces."""
    lines = [
        "",
        "Every word a teacher says per run, mean over the tasks: the words understood while "
        "the robot learns, the commands said to dictate the initial traces (a command lasts "
        "`command_steps` steps, so a run of one command takes a word per that many steps), "
        "and their sum.",
        "",
        "| setting | while learning | dictating traces | in all |",
        "|---|---|---|---|",
    ]
    for s in feedback:
        learning, dictating = summary["interventions"][s], summary["trace_words"][s]
        lines.append(
            f"| {LABELS[s]} | {learning:.1f} | {dictating:.1f} | {learning + dictating:.1f} |"
        )
    return lines


def _asking(summary: dict, settings: list[str]) -> list[str]:
    """The robot that asks which way against the same learner that does not (when both ran)."""
    pairs = [(s, s.removesuffix("+ask")) for s in settings if SETTINGS[s].ask]
    pairs = [(ask, plain) for ask, plain in pairs if plain in settings]
    if not pairs:
        return []
    lines = [
        "",
        "## Asking which way",
        "",
        'The robot asks "which way?" when it is stuck, late in an episode or unsure '
        "(services/learner/asking.py); the person answers within its word budget. Learning "
        "time is the mean over the tasks; the speedup is the same learner's time without asking "
        "over its time with; the timeout share is the robot's time until convergence spent "
        "in episodes that timed out.",
        "",
        "| setting | learning time min | speedup from asking | timeout share | questions "
        "| answers | words while learning |",
        "|---|---|---|---|---|---|---|",
    ]
    means, share = summary["mean_learning_time_s"], summary["timeout_share"]
    for ask, plain in pairs:
        asked = summary["questions"][ask]
        lines.append(
            f"| {LABELS[plain]} | {means[plain] / 60:.1f} | - | {share[plain]:.2f} | - | - | "
            f"{summary['interventions'][plain]:.1f} |"
        )
        lines.append(
            f"| {LABELS[ask]} | {means[ask] / 60:.1f} | {means[plain] / means[ask]:.2f} | "
            f"{share[ask]:.2f} | {asked['asked']:.1f} | {asked['answered']:.1f} | "
            f"{summary['interventions'][ask]:.1f} |"
        )
    return lines


def _noisy_against_perfect(summary: dict) -> list[str]:
    """Task 2 with traces, noisy against perfect feedback, as the paper compares them (when
    both were run)."""
    noisy, perfect = "rl+t+f", "rl+t+f-perfect"
    if "2" not in summary["tasks"] or not {noisy, perfect} <= set(summary["tasks"]["2"]):
        return []
    lines = [
        "",
        "Task 2 with initial traces, noisy (20%) against perfect feedback (PF):",
        "",
        "| | time (min) ours | paper | interventions ours | paper |",
        "|---|---|---|---|---|",
    ]
    for setting, name in ((noisy, "T2"), (perfect, "T2 PF")):
        lines.append(
            f"| {name} | {_cell(summary, '2', setting, 'learning_time_s', 60)} | "
            f"{_paper(PAPER_MINUTES, setting, '2')} | "
            f"{_cell(summary, '2', setting, 'interventions')} | "
            f"{_paper(PAPER_INTERVENTIONS, setting, '2')} |"
        )
    return lines


_FIGURE2_SECTION = (
    "",
    "## Figure 2",
    "",
    "![episode duration against episode](figure2.png)",
    "",
    "Mean episode duration (robot minutes) of the runs still learning at each episode, "
    "over all tasks and seeds, one line per setting, as long as a quarter of its runs "
    "(3 at least) are.",
    "",
)


def figure2(results: list[RunResult], path: Path) -> None:
    """Episode duration (minutes) against episode, one line per setting, averaged over the
    runs (all tasks and seeds) that are still learning at that episode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    markers = {"rl": "s", "rl+f": "D", "rl+t+f": "^", "rl+t+f-perfect": "v"}
    markers.update({"rl+f+ask": "o", "rl+t+f+ask": "P"})
    fig, ax = plt.subplots(figsize=(7, 4))
    for setting in SETTINGS:
        runs = [r.durations_s[: r.episodes] for r in results if r.setting == setting]
        if not runs:
            continue
        # Up to the last episode that a quarter of the runs (3 at least) still learn: beyond,
        # a line is the noise of a few slow runs.
        enough = min(len(runs), max(3, len(runs) // 4))
        longest = max(i for i in range(1, max(len(d) for d in runs) + 1)
                      if sum(len(d) >= i for d in runs) >= enough)  # fmt: skip
        mean = [statistics.fmean(d[i] for d in runs if len(d) > i) / 60 for i in range(longest)]
        ax.plot(range(1, longest + 1), mean, marker=markers[setting], markersize=3,
                label=LABELS[setting])  # fmt: skip
    ax.set_xlabel("episode")
    ax.set_ylabel("episode duration (robot minutes)")
    ax.set_title("Average episode duration over the tasks (cf. the paper's Figure 2)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


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
    summary = summarize(results, len(seeds))
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
    (out / "report.md").write_text(report(summary, summary["command"], summary["wall_time_s"]))
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
            runs += [RunResult(**r) for r in results["runs"]]
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
    summary = summarize(runs, len({r.seed for r in runs}))
    summary["first_seed"] = min(r.seed for r in runs)
    summary.update({key: loaded[0].get(key) for key in POOLED_ALIKE})
    summary.update(
        command=command,
        wall_time_s=round(sum(results.get("wall_time_s", 0.0) for results in loaded), 1),
        pooled=[str(d) for d in dirs],
    )
    _write(out, summary, runs)
    return summary

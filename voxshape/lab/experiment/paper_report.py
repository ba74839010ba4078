"""report.md of `voxshape experiment paper`: Tables 2 and 3 in the paper's layout, ours beside
the paper's figures, then the sections after them (SECTIONS, in order)."""

from __future__ import annotations

import os
import statistics
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from voxshape.lab.experiment.inprocess import SETTINGS
from voxshape.lab.experiment.intervals import few_seeds_note
from voxshape.lab.experiment.legend import label, teacher_line
from voxshape.lab.experiment.published import (
    PAPER_EPISODES,
    PAPER_INTERVENTIONS,
    PAPER_MINUTES,
    TASKS,
    paper_average,
)
from voxshape.services.learner.config import with_settings
from voxshape.services.learner.convergence import Convergence


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


def _built_in_row(
    summary: dict, built_in: list[str], settings: list[str], key: str, paper: dict
) -> str:
    """The row of the built-in tasks alone, ours beside the paper's (minutes or counts)."""
    scale = 60 if key == "robot_time_s" else 1
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
    """The tasks and settings a report covers, and the paper's figures over the same built-in
    tasks."""

    tasks: list[str]
    built_in: list[str]  # the built-in tasks among them: map files have no paper figures
    paper: dict[str, dict[str, float]]  # paper_average over built_in
    settings: list[str]  # those run, in the order of inprocess.SETTINGS
    feedback: list[str]  # those of them in which the teacher judges

    @classmethod
    def of(cls, summary: dict) -> _Scope:
        tasks = list(summary["tasks"])
        built_in = [t for t in tasks if t in TASKS]
        settings = [s for s in SETTINGS if any(s in summary["tasks"][t] for t in tasks)]
        feedback = [s for s in settings if SETTINGS[s].feedback]
        return cls(tasks, built_in, paper_average(built_in), settings, feedback)

    @property
    def mixed(self) -> bool:
        """Built-in tasks and map files: the paper's figures go on rows of the built-in alone."""
        return bool(self.built_in) and len(self.built_in) < len(self.tasks)

    @property
    def average_label(self) -> str:
        return "Avg" if self.tasks == list(TASKS) else f"Avg of {_labels(self.tasks)}"


def report(summary: dict, command: str, wall_seconds: float) -> str:
    """The Markdown report: what was run, then each of SECTIONS (Tables 2 and 3 in the
    paper's layout, ours beside the paper's, and what follows them)."""
    scope = _Scope.of(summary)
    lines = _introduction(summary, command, wall_seconds)
    for section in SECTIONS:
        lines += section(summary, scope)
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
        f"{wall_seconds / 60:.1f} min of wall time on {os.cpu_count()} cores. "
        + teacher_line(summary),
        "",
        "Ours: mean ± half-width of the 95% confidence interval (Student's t) over seeds. "
        "Learning time is the robot's simulated time until convergence ("
        + Convergence(with_settings(summary.get("learner_settings", []))).rule()
        + ", the shortest time of each task's map); with initial traces, the robot's time "
        "they took to dictate comes first and is counted. **Censored runs**: a run that did not "
        "converge within the episode limit counts with its time so far, so its cell's mean "
        f"is a lower bound, marked ≥ ({len(censored)} of {len(runs)} runs censored{named}).",
        "",
        *([note, ""] if (note := few_seeds_note(summary["seeds"])) else []),
    ]


def _table2(summary: dict, scope: _Scope) -> list[str]:
    """Table 2: episodes, then learning time in minutes with its averages over the tasks."""
    settings = scope.settings
    lines = ["## Table 2: episodes (left) and learning time in minutes (right)", ""]
    lines += ["Episodes:", "", *_head(settings)]
    lines += _task_rows(summary, scope.tasks, settings, "episodes", PAPER_EPISODES)
    lines += ["", "Robot time (minutes), the dictation of traces included:", "", *_head(settings)]
    lines += _task_rows(summary, scope.tasks, settings, "robot_time_s", PAPER_MINUTES, 60)
    minutes = {s: summary["mean_robot_time_s"][s] / 60 for s in settings}
    lines += _average_rows(summary, scope, settings, "robot_time_s", minutes, "minutes")
    note = paper_note(scope.tasks, scope.built_in)
    return lines + (["", note] if note else [])


BOUND_MARKS = {"exact": "", "lower": "≥ ", "upper": "≤ ", "none": "~ "}
BOUND_NOTES = {
    "lower": "≥: only RL had censored runs, so the speedup is a lower bound.",
    "upper": "≤: only the setting had censored runs, so the speedup is an upper bound.",
    "none": "~: both RL and the setting had censored runs: the speedup is no bound either way.",
}


def _speedups(summary: dict, scope: _Scope) -> list[str]:
    """Each setting's speedup over RL with its bootstrap interval, beside the paper's, marked
    where censored runs make it a bound."""
    lines = ["", "Speedup over RL (mean RL robot time over the tasks / the setting's):", ""]
    lines += ["| setting | ours | 95% interval | paper |", "|---|---|---|---|"]
    bounds = summary["speedup_bound"]
    for setting, value in summary["speedup"].items():
        theirs = "-" if scope.mixed else _figure(scope.paper["speedup"].get(setting))
        low, high = summary["speedup_ci95"][setting]
        mark = BOUND_MARKS[bounds[setting]]
        lines.append(f"| {label(setting)} | {mark}{value:.2f} | {low:.2f}-{high:.2f} | {theirs} |")
    if scope.mixed and summary["speedup"]:
        lines += _built_in_speedups(summary, scope)
    notes = [BOUND_NOTES[b] for b in dict.fromkeys(bounds.values()) if b in BOUND_NOTES]
    return lines + (["", " ".join(notes)] if notes else [])


def _built_in_speedups(summary: dict, scope: _Scope) -> list[str]:
    """The speedups over the built-in tasks alone, against the paper's over them."""
    lines = [
        "",
        f"On the built-in tasks alone ({_labels(scope.built_in)}), against the paper's "
        "speedups over them:",
        "",
        "| setting | ours | paper |",
        "|---|---|---|",
    ]
    rl = _over(summary, scope.built_in, "rl", "robot_time_s")
    for setting in summary["speedup"]:
        ours = _over(summary, scope.built_in, setting, "robot_time_s")
        bound = BOUND_MARKS[summary["speedup_bound"][setting]]
        value = "-" if rl is None or not ours else f"{bound}{rl / ours:.2f}"
        lines.append(
            f"| {label(setting)} | {value} | {_figure(scope.paper['speedup'].get(setting))} |"
        )
    return lines


def _table3(summary: dict, scope: _Scope) -> list[str]:
    """Table 3: the interventions of each feedback setting, with their averages."""
    feedback = scope.feedback
    lines = [
        "",
        "## Table 3: interventions (words said while learning, heard or not, until convergence)",
        "",
    ]
    lines += _head(feedback)
    lines += _task_rows(summary, scope.tasks, feedback, "interventions", PAPER_INTERVENTIONS)
    interventions = summary["interventions"]
    return lines + _average_rows(
        summary, scope, feedback, "interventions", interventions, "interventions"
    )


def _head(settings: list[str]) -> list[str]:
    """A table's header: per setting, ours and the paper's."""
    return [
        "| task | " + " | ".join(f"{label(s)} ours | paper" for s in settings) + " |",
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


def _teacher_words(summary: dict, scope: _Scope) -> list[str]:
    """Every word a person says per run, and what each bought: the robot seconds saved over
    plain RL, per word."""
    taught = list(summary["words"])
    if not taught:
        return []
    lines = [
        "",
        "Every word the person says per run, mean over the tasks: the commands said to dictate "
        "the initial traces, the words said while the robot learns (heard or not), their sum, the "
        "robot minutes the dictation took, and the robot seconds each word saved (plain RL's "
        "mean robot time less the setting's, dictation included, over its words).",
        "",
        "| setting | dictating traces | while learning | in all | dictation min "
        "| seconds saved a word |",
        "|---|---|---|---|---|---|",
    ]
    saved = summary["seconds_saved_per_word"]
    for s in taught:
        learning, dictating = summary["interventions"][s], summary["dictation_words"][s]
        per_word = f"{saved[s]:.1f}" if s in saved else "-"
        lines.append(
            f"| {label(s)} | {dictating:.1f} | {learning:.1f} | {learning + dictating:.1f} | "
            f"{summary['mean_dictation_s'][s] / 60:.1f} | {per_word} |"
        )
    return lines


def _time_lost(summary: dict, scope: _Scope) -> list[str]:
    """Where the robot's learning time went (bump bouts, timeouts) and which way the
    person's input pushed it."""
    lines = [
        "",
        "Where the robot's time went until convergence, per setting: the share in bump bouts "
        "of 10 s or more (a robot pinned to a wall) and in episodes that timed out; and which "
        "way the person pushed: the share of the robot's decisions (greedy or commanded) that "
        "the person's input changed against what it would have done alone, and of those the "
        "share that led along the map's true shortest way.",
        "",
        "| setting | bump bouts | timeouts | changed by the person | of those, toward the way |",
        "|---|---|---|---|---|",
    ]
    changed, toward = summary.get("changed_by_person", {}), summary.get("changed_toward_way", {})
    for s in scope.settings:
        by = f"{changed[s]:.3f}" if s in changed else "-"
        way = f"{toward[s]:.2f}" if toward.get(s) is not None else "-"
        lines.append(
            f"| {label(s)} | {summary['bump_bout_share'][s]:.3f} | "
            f"{summary['timeout_share'][s]:.2f} | {by} | {way} |"
        )
    return lines


def _asking(summary: dict, scope: _Scope) -> list[str]:
    """The robot that asks which way against the same learner that does not (when both ran)."""
    pairs = [(s, s.removesuffix("+ask")) for s in scope.settings if SETTINGS[s].ask]
    pairs = [(ask, plain) for ask, plain in pairs if plain in scope.settings]
    if not pairs:
        return []
    lines = [
        "",
        "## Asking which way",
        "",
        'The robot asks "which way?" when it is stuck, late in an episode or unsure '
        "(voxshape/services/learner/asking.py); the person answers within its word budget. "
        "Learning time is the mean over the tasks; the speedup is the same learner's time "
        "without asking over its time with; the timeout share is the robot's time until "
        "convergence spent in episodes that timed out.",
        "",
        "| setting | learning time min | speedup from asking | timeout share | questions "
        "| answers | words while learning |",
        "|---|---|---|---|---|---|---|",
    ]
    means, share = summary["mean_robot_time_s"], summary["timeout_share"]
    for ask, plain in pairs:
        asked = summary["questions"][ask]
        lines.append(
            f"| {label(plain)} | {means[plain] / 60:.1f} | - | {share[plain]:.2f} | - | - | "
            f"{summary['interventions'][plain]:.1f} |"
        )
        lines.append(
            f"| {label(ask)} | {means[ask] / 60:.1f} | {means[plain] / means[ask]:.2f} | "
            f"{share[ask]:.2f} | {asked['asked']:.1f} | {asked['answered']:.1f} | "
            f"{summary['interventions'][ask]:.1f} |"
        )
    return lines


def _noisy_against_perfect(summary: dict, scope: _Scope) -> list[str]:
    """Task 2 with traces, noisy against perfect feedback, as the paper compares them (when
    both were run)."""
    noisy, perfect = "rl+t+f", "rl+t+f-perfect"
    if "2" not in summary["tasks"] or not {noisy, perfect} <= set(summary["tasks"]["2"]):
        return []
    lines = [
        "",
        "Task 2 with initial traces, noisy (28%) against perfect feedback (PF):",
        "",
        "| | time (min) ours | paper | interventions ours | paper |",
        "|---|---|---|---|---|",
    ]
    for setting, name in ((noisy, "T2"), (perfect, "T2 PF")):
        lines.append(
            f"| {name} | {_cell(summary, '2', setting, 'robot_time_s', 60)} | "
            f"{_paper(PAPER_MINUTES, setting, '2')} | "
            f"{_cell(summary, '2', setting, 'interventions')} | "
            f"{_paper(PAPER_INTERVENTIONS, setting, '2')} |"
        )
    return lines


def _figure2(summary: dict, scope: _Scope) -> list[str]:
    """The paper's Figure 2 again (figure2.py draws it) and how it is averaged."""
    return [
        "",
        "## Figure 2",
        "",
        "![episode duration against episode](figure2.png)",
        "",
        "Mean episode duration (robot minutes) of the runs still learning at each episode, "
        "over all tasks and seeds, one line per setting, as long as a quarter of its runs "
        "(3 at least) are.",
        "",
    ]


# report.md's sections after its introduction, in order; each is (summary, scope) -> lines,
# and says nothing (no lines) when the runs have nothing for it.
SECTIONS: tuple[Callable[[dict, _Scope], list[str]], ...] = (
    _table2,
    _speedups,
    _table3,
    _teacher_words,
    _time_lost,
    _asking,
    _noisy_against_perfect,
    _figure2,
)

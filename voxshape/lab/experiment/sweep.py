"""`voxshape experiment sweep`: how the speedup of feedback (`rl+f`) over plain RL changes with
the recognition noise, the teacher's reaction delay (with and without the arbiter's delay
correction) and how often the teacher speaks later on: the paper's open questions 1-3; and
with the teacher's word budget (`--rate`: how much talking buys how much speedup).

Every point is `rl+f` on the chosen tasks and seeds with one thing changed from the paper's
setting (28% noise, 0.5 s delay, delay correction on) taught by the `--teacher-profile` teacher
(a person, by default); a rate point is `rl+f` and `rl+t+f` with a person speaking at
salient moments within a budget of that many words a robot minute (0: the tireless
teacher, every look). Its speedup is
the mean RL learning time over the tasks divided by its own (the paper's ratio), with a 95%
bootstrap interval (seeds resampled within each task). Writes sweep.json, sweep.md and
sweep.png (speedup curves with those intervals) to the output directory.
"""

from __future__ import annotations

import json
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from voxshape.lab.experiment.inprocess import SETTINGS, RunResult, RunSpec
from voxshape.lab.experiment.intervals import few_seeds_note, speedup_interval, task_means
from voxshape.lab.experiment.legend import SETTING_STYLES
from voxshape.lab.experiment.runner import run_all, start_log
from voxshape.services.simteacher.teacher import PERSON, PROFILES, TIRELESS, TeacherProfile

FEEDBACK, TRACES = "rl+f", "rl+t+f"


@dataclass(frozen=True)
class Point:
    axis: str  # noise, delay, frequency, rate (or rl: the baseline)
    value: float
    correction: bool = True  # the arbiter learns the teacher's delay
    setting: str = FEEDBACK

    @property
    def label(self) -> str:
        if self.axis == "delay":
            return f"delay {self.value:g} s, correction {'on' if self.correction else 'off'}"
        if self.axis == "rate":
            rate = f"{self.value:g} words/min" if self.value else "tireless"
            return f"{rate}, {SETTING_STYLES[self.setting].label}"
        return f"{self.axis} {self.value:g}"


def spec_of(
    point: Point,
    task: str,
    seed: int,
    max_episodes: int,
    learner: tuple[str, ...] = (),
    teacher: tuple[str, ...] = (),
    profile: TeacherProfile = PERSON,
) -> RunSpec:
    """The run of a point: `profile` with the point's change, then `teacher`'s changes; a
    rate point is a person with that budget (0: the tireless teacher)."""
    if point.axis == "rl":
        return RunSpec(task, "rl", seed, max_episodes, learner=learner)
    if point.axis == "rate":
        budget = replace(PERSON, words_per_robot_minute=point.value) if point.value else TIRELESS
        return RunSpec(
            task, point.setting, seed, max_episodes, profile=budget, learner=learner,
            teacher=teacher,
        )  # fmt: skip
    spec = RunSpec(
        task,
        FEEDBACK,
        seed,
        max_episodes,
        delay_learning=point.correction,
        profile=profile,
        learner=learner,
        teacher=teacher,
    )
    if point.axis == "noise":
        return replace(spec, noise=point.value)
    if point.axis == "delay":
        return replace(spec, delay=point.value)
    schedule = replace(profile.schedule, sporadic=point.value)
    return replace(spec, profile=replace(profile, schedule=schedule))


def points_of(
    noise: list[float], delay: list[float], frequency: list[float], rate: Sequence[float] = ()
) -> list[Point]:
    return [
        Point("rl", 0.0),
        *(Point("noise", v) for v in noise),
        *(Point("delay", v, correction) for v in delay for correction in (True, False)),
        *(Point("frequency", v) for v in frequency),
        *(Point("rate", v, setting=s) for s in (FEEDBACK, TRACES) for v in rate),
    ]


def summarize_points(
    points: list[Point], results: dict[Point, list[RunResult]], tasks: list[str]
) -> list[dict]:
    rl_runs = results[points[0]]
    rl = task_means(rl_runs, tasks)
    rows = []
    for point in points:
        runs = results[point]
        robot_time = task_means(runs, tasks)  # dictation included
        rows.append(
            {
                "axis": point.axis,
                "value": point.value,
                "correction": point.correction,
                "setting": point.setting if point.axis != "rl" else "rl",
                "label": point.label,
                "runs": len(runs),
                "mean_robot_time_s": robot_time,
                "speedup": rl / robot_time,
                "speedup_ci95": speedup_interval(rl_runs, runs, tasks),
                "interventions": statistics.fmean(r.interventions for r in runs),
                # words said while learning, per robot minute of learning
                "words_per_minute": sum(r.interventions for r in runs)
                / (sum(r.learning_time_s for r in runs) / 60),
                "mean_learning_time_s": statistics.fmean(r.learning_time_s for r in runs),
                "converged_fraction": sum(r.converged for r in runs) / len(runs),
                "delay_learned_fraction": sum(r.delay_learned for r in runs) / len(runs),
            }
        )
    return rows


def table(rows: list[dict]) -> str:
    lines = [
        "| point | speedup over RL | 95% interval | robot time min (mean over tasks) "
        "| interventions | words per robot minute | converged | delay learnt |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        learnt = f"{row['delay_learned_fraction']:.2f}" if row["axis"] != "rl" else "-"
        low, high = row["speedup_ci95"]
        lines.append(
            f"| {row['label'] if row['axis'] != 'rl' else 'RL (baseline)'} | "
            f"{row['speedup']:.2f} | {low:.2f}-{high:.2f} | "
            f"{row['mean_robot_time_s'] / 60:.1f} | "
            f"{row['interventions']:.0f} | {row['words_per_minute']:.1f} | "
            f"{row['converged_fraction']:.2f} | {learnt} |"
        )
    return "\n".join(lines)


def figure(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axes = [a for a in ("noise", "delay", "frequency", "rate") if any(r["axis"] == a for r in rows)]
    fig, plots = plt.subplots(1, len(axes), figsize=(4.5 * len(axes), 3.6), squeeze=False)
    names = {"noise": "noise rate", "delay": "reaction delay (s)", "frequency": "late feedback"}
    names["rate"] = "words understood per robot minute"
    for plot, axis in zip(plots[0], axes, strict=True):
        if axis == "rate":
            _budget_curve(plot, [r for r in rows if r["axis"] == "rate"])
        for correction in (True, False) if axis != "rate" else ():
            line = [r for r in rows if r["axis"] == axis and r["correction"] == correction]
            if line:
                label = None if axis != "delay" else f"correction {'on' if correction else 'off'}"
                xs, ys = [r["value"] for r in line], [r["speedup"] for r in line]
                low = [y - r["speedup_ci95"][0] for y, r in zip(ys, line, strict=True)]
                high = [r["speedup_ci95"][1] - y for y, r in zip(ys, line, strict=True)]
                plot.errorbar(xs, ys, yerr=[low, high], marker="o", capsize=3, label=label)
        plot.axhline(1.0, color="grey", linewidth=0.8)
        plot.set_xlabel(names[axis])
        plot.set_ylabel("speedup over RL")
        if axis in ("delay", "rate"):
            plot.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _budget_curve(plot: object, rows: list[dict]) -> None:
    """Speedup against the words the teacher said per robot minute, a line per setting,
    each point labelled with its budget."""
    for setting in (FEEDBACK, TRACES):
        line = sorted(
            (r for r in rows if r["setting"] == setting),
            key=lambda r: r["words_per_minute"],
        )
        xs, ys = [r["words_per_minute"] for r in line], [r["speedup"] for r in line]
        low = [y - r["speedup_ci95"][0] for y, r in zip(ys, line, strict=True)]
        high = [r["speedup_ci95"][1] - y for y, r in zip(ys, line, strict=True)]
        plot.errorbar(
            xs, ys, yerr=[low, high], marker="o", capsize=3, label=SETTING_STYLES[setting].label
        )
        for x, y, r in zip(xs, ys, line, strict=True):
            plot.annotate(f"{r['value']:g}" if r["value"] else "tireless", (x, y), fontsize=7)
    plot.set_xscale("log")


def sweep(
    out: Path,
    tasks: list[str],
    seeds: range,
    max_episodes: int,
    noise: list[float],
    delay: list[float],
    frequency: list[float],
    rate: Sequence[float] = (),
    workers: int | None = None,
    progress: bool = True,
    learner: tuple[str, ...] = (),
    teacher: tuple[str, ...] = (),
    profile: str = "person",
    cluster: str | None = None,
    resume: bool = False,
) -> list[dict]:
    """Runs the sweep; writes sweep.json, sweep.md and sweep.png to `out`; points but the
    rate's change the simulated teacher's `profile`; `cluster` and `resume` as in
    paper.experiment."""
    assert SETTINGS[FEEDBACK].feedback
    points = points_of(noise, delay, frequency, rate)
    jobs = [
        (p, spec_of(p, t, s, max_episodes, learner, teacher, PROFILES[profile]))
        for p in points
        for t in tasks
        for s in seeds
    ]
    results: dict[Point, list[RunResult]] = {p: [] for p in points}
    out.mkdir(parents=True, exist_ok=True)
    specs = [spec for _, spec in jobs]
    done = start_log(out / "runs.jsonl", specs, resume)
    ran = run_all(specs, workers, progress, out / "runs.jsonl", cluster=cluster, done=done)
    for (point, _), result in zip(jobs, ran, strict=True):
        results[point].append(result)
    rows = summarize_points(points, results, tasks)
    (out / "sweep.json").write_text(
        json.dumps(
            {
                "tasks": tasks,
                "seeds": len(seeds),
                "first_seed": seeds.start,
                "max_episodes": max_episodes,
                "learner_settings": list(learner),
                "teacher_settings": list(teacher),
                "teacher_profile": profile,
                "points": rows,
            },
            indent=1,
        )
    )
    (out / "sweep.md").write_text(table(rows) + "\n" + _notes(rows, len(seeds)))
    figure(rows, out / "sweep.png")
    return rows


def _notes(rows: list[dict], seeds: int) -> str:
    """What sweep.md says below its table: RL's censored runs, too few seeds."""
    note = (
        "\nRL did not always converge within the episode limit: its mean is a lower bound, and "
        "so is every speedup.\n"
        if rows[0]["converged_fraction"] < 1
        else ""
    )
    if few := few_seeds_note(seeds):
        note += f"\n{few}\n"
    return note

"""`voxshape experiment sweep`: how the speedup of feedback (`rl+f`) over plain RL changes with
the recognition noise, the teacher's reaction delay (with and without the arbiter's delay
correction) and how often the teacher speaks later on: the paper's open questions 1-3.

Every point is `rl+f` on the chosen tasks and seeds with one thing changed from the paper's
setting (20% noise, 0.5 s delay, delay correction on, sporadic feedback 20%); its speedup is
the mean RL learning time over the tasks divided by its own (the paper's ratio), with a 95%
bootstrap interval (seeds resampled within each task). Writes sweep.json, sweep.md and
sweep.png (speedup curves with those intervals) to the output directory.
"""

from __future__ import annotations

import json
import statistics
from dataclasses import dataclass, replace
from pathlib import Path

from services.experiment.inprocess import SETTINGS, RunResult, RunSpec
from services.experiment.paper import run_all, speedup_interval, task_means
from services.simteacher.teacher import TeacherProfile

FEEDBACK = "rl+f"


@dataclass(frozen=True)
class Point:
    axis: str  # noise, delay, frequency (or rl: the baseline)
    value: float
    correction: bool = True  # the arbiter learns the teacher's delay

    @property
    def label(self) -> str:
        if self.axis == "delay":
            return f"delay {self.value:g} s, correction {'on' if self.correction else 'off'}"
        return f"{self.axis} {self.value:g}"


def spec_of(
    point: Point,
    task: str,
    seed: int,
    max_episodes: int,
    learner: tuple[str, ...] = (),
    teacher: tuple[str, ...] = (),
) -> RunSpec:
    if point.axis == "rl":
        return RunSpec(task, "rl", seed, max_episodes, learner=learner)
    spec = RunSpec(
        task,
        FEEDBACK,
        seed,
        max_episodes,
        delay_learning=point.correction,
        learner=learner,
        teacher=teacher,
    )
    if point.axis == "noise":
        return replace(spec, noise=point.value)
    if point.axis == "delay":
        return replace(spec, delay=point.value)
    schedule = replace(TeacherProfile().schedule, sporadic=point.value)
    return replace(spec, profile=replace(TeacherProfile(), schedule=schedule))


def points_of(noise: list[float], delay: list[float], frequency: list[float]) -> list[Point]:
    return [
        Point("rl", 0.0),
        *(Point("noise", v) for v in noise),
        *(Point("delay", v, correction) for v in delay for correction in (True, False)),
        *(Point("frequency", v) for v in frequency),
    ]


def summarize_points(
    points: list[Point], results: dict[Point, list[RunResult]], tasks: list[str]
) -> list[dict]:
    rl_runs = results[points[0]]
    rl = task_means(rl_runs, tasks)
    rows = []
    for point in points:
        runs = results[point]
        learning_time = task_means(runs, tasks)
        rows.append(
            {
                "axis": point.axis,
                "value": point.value,
                "correction": point.correction,
                "label": point.label,
                "runs": len(runs),
                "mean_learning_time_s": learning_time,
                "speedup": rl / learning_time,
                "speedup_ci95": speedup_interval(rl_runs, runs, tasks),
                "interventions": statistics.fmean(r.interventions for r in runs),
                "converged_fraction": sum(r.converged for r in runs) / len(runs),
                "delay_learned_fraction": sum(r.delay_learned for r in runs) / len(runs),
            }
        )
    return rows


def table(rows: list[dict]) -> str:
    lines = [
        "| point | speedup over RL | 95% interval | learning time min (mean over tasks) "
        "| interventions | converged | delay learnt |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        learnt = f"{row['delay_learned_fraction']:.2f}" if row["axis"] != "rl" else "-"
        low, high = row["speedup_ci95"]
        lines.append(
            f"| {row['label'] if row['axis'] != 'rl' else 'RL (baseline)'} | "
            f"{row['speedup']:.2f} | {low:.2f}-{high:.2f} | "
            f"{row['mean_learning_time_s'] / 60:.1f} | "
            f"{row['interventions']:.0f} | {row['converged_fraction']:.2f} | {learnt} |"
        )
    return "\n".join(lines)


def figure(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axes = [a for a in ("noise", "delay", "frequency") if any(r["axis"] == a for r in rows)]
    fig, plots = plt.subplots(1, len(axes), figsize=(4.5 * len(axes), 3.6), squeeze=False)
    names = {"noise": "noise rate", "delay": "reaction delay (s)", "frequency": "late feedback"}
    for plot, axis in zip(plots[0], axes, strict=True):
        for correction in (True, False):
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
        if axis == "delay":
            plot.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def sweep(
    out: Path,
    tasks: list[str],
    seeds: range,
    max_episodes: int,
    noise: list[float],
    delay: list[float],
    frequency: list[float],
    workers: int | None = None,
    progress: bool = True,
    learner: tuple[str, ...] = (),
    teacher: tuple[str, ...] = (),
) -> list[dict]:
    """Runs the sweep; writes sweep.json, sweep.md and sweep.png to `out`."""
    assert SETTINGS[FEEDBACK].feedback
    points = points_of(noise, delay, frequency)
    jobs = [
        (p, spec_of(p, t, s, max_episodes, learner, teacher))
        for p in points
        for t in tasks
        for s in seeds
    ]
    results: dict[Point, list[RunResult]] = {p: [] for p in points}
    out.mkdir(parents=True, exist_ok=True)
    (out / "runs.jsonl").unlink(missing_ok=True)
    done = run_all([spec for _, spec in jobs], workers, progress, log=out / "runs.jsonl")
    for (point, _), result in zip(jobs, done, strict=True):
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
                "points": rows,
            },
            indent=1,
        )
    )
    note = (
        "\nRL did not always converge within the episode limit: its mean is a lower bound, and "
        "so is every speedup.\n"
        if rows[0]["converged_fraction"] < 1
        else ""
    )
    (out / "sweep.md").write_text(table(rows) + "\n" + note)
    figure(rows, out / "sweep.png")
    return rows

"""The experiments' confidence intervals: Student's t for a mean over seeds, and a seeded
bootstrap for a speedup (a ratio of means over tasks)."""

from __future__ import annotations

import math
import random
import statistics
from collections.abc import Iterable
from operator import attrgetter

from voxshape.lab.experiment.inprocess import RunResult

# Student's t, two-sided 95%, by degrees of freedom (1-30); beyond, the normal's 1.96.
T95 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179,
       2.160, 2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064,
       2.060, 2.056, 2.052, 2.048, 2.045, 2.042)  # fmt: skip


FEW_SEEDS = 5  # below this many seeds a cell's interval is too wide to decide anything


def few_seeds_note(seeds: int) -> str | None:
    """What to say of an experiment of `seeds` seeds per cell, when they are too few for its
    intervals to mean much; None when they are enough."""
    if seeds >= FEW_SEEDS:
        return None
    t = f"Student's t of {T95[seeds - 2]:g}" if seeds >= 2 else "no spread at all from one seed"
    return (
        f"**Too few seeds to say much**: {seeds} seed(s) per task and setting ({t}), so the "
        "intervals here are wider than most of the differences they would decide, and a "
        f"mean can move by its own size with one more seed. Run --seeds {FEW_SEEDS} or more "
        "(the stored results use 10) before reading a difference off these tables."
    )


def mean_ci(values: Iterable[float]) -> tuple[float, float]:
    """The mean and the half-width of its 95% confidence interval (Student's t; 0 for n=1)."""
    values = list(values)
    mean = statistics.fmean(values)
    if len(values) < 2:
        return mean, 0.0
    t = T95[len(values) - 2] if len(values) - 1 <= len(T95) else 1.96
    return mean, t * statistics.stdev(values) / math.sqrt(len(values))


def task_means(runs: list[RunResult], tasks: list[str]) -> float:
    """The mean over the tasks of the mean robot time of each, dictation included (the
    paper's average)."""
    return statistics.fmean(
        statistics.fmean(r.robot_time_s for r in runs if r.task == t) for t in tasks
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

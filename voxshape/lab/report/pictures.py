"""The report's pictures, headless matplotlib: the map with the paths of a few episodes, the
learning curve (returns, steps, interventions), and the rewards over the steps (the teacher's
words, what each step was credited, when things arrived)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: no display needed
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.patches import Circle, FancyArrow, Polygon
from matplotlib.ticker import MaxNLocator

from voxshape.lab.report.counts import EpisodeCounts
from voxshape.lab.report.summary import MOVING_AVERAGE, STEP_SECONDS, EpisodeSummary, RobotSummary
from voxshape.world.maps import Box, Cylinder, Map

MAX_EPISODES_DRAWN = 6


def pick_episodes(robot: RobotSummary, wanted: Sequence[str] | None = None) -> list[EpisodeSummary]:
    """The episodes to draw: those asked for (numbers, or run:number), else the first, the
    best, a middle one and the last that ended (at most MAX_EPISODES_DRAWN)."""
    if wanted:
        return [robot.find(str(label)) for label in wanted][:MAX_EPISODES_DRAWN]
    ended = robot.ended or robot.episodes
    if not ended:
        return []
    best = max(ended, key=lambda e: (e.env_return, -e.position))
    chosen = {id(e): e for e in (ended[0], best, ended[len(ended) // 2], ended[-1])}
    return sorted(chosen.values(), key=lambda e: e.position)


# -- pictures ------------------------------------------------------------------------------------


def draw_map(ax: Axes, m: Map) -> None:
    """Walls and obstacles, goal and start, y-up in metres."""
    for shape in m.shapes:
        if isinstance(shape, Box):
            ax.add_patch(Polygon(shape.corners(), closed=True, color="#404040"))
        elif isinstance(shape, Cylinder):
            ax.add_patch(Circle((shape.x, shape.y), shape.radius, color="#404040"))
    ax.add_patch(Circle((m.goal_x, m.goal_y), m.goal_radius, color="#2ca02c", alpha=0.35))
    s = m.start
    ax.add_patch(
        FancyArrow(
            s.x, s.y, 0.4 * math.cos(s.theta), 0.4 * math.sin(s.theta), width=0.06, color="#1f77b4"
        )
    )
    ax.set_xlim(-0.2, m.width + 0.2)
    ax.set_ylim(-0.2, m.height + 0.2)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")


def draw_trajectories(
    m: Map, episodes: Sequence[EpisodeSummary], robot: RobotSummary, path: Path
) -> None:
    scale = 6.0 / max(m.width, m.height)
    fig, ax = plt.subplots(figsize=(m.width * scale + 2.6, m.height * scale + 0.6), dpi=100)
    try:
        draw_map(ax, m)
        colors = plt.get_cmap("viridis")(np.linspace(0, 0.9, max(1, len(episodes))))
        for e, color in zip(episodes, colors, strict=False):
            label = f"ep {robot.label(e)}: {e.outcome}, {e.steps or len(e.xs)} steps"
            ax.plot(e.xs, e.ys, color=color, lw=1.4, label=label)
            if e.xs:
                ax.plot(e.xs[-1], e.ys[-1], "o", color=color, ms=4)
        ax.set_title(f"{m.name}: robot {robot.robot}", fontsize=10)
        if episodes:
            ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=7)
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)


def moving_average(values: Sequence[float], n: int = MOVING_AVERAGE) -> np.ndarray:
    """The mean of each value and the up to n-1 before it."""
    v = np.asarray(values, dtype=float)
    c = np.cumsum(np.insert(v, 0, 0.0))
    i = np.arange(1, len(v) + 1)
    lo = np.maximum(0, i - n)
    return (c[i] - c[lo]) / (i - lo)


def robust_limits(values: Sequence[float], fence: float = 3.0) -> tuple[float, float] | None:
    """y-limits that keep a few far values (a first episode's huge negative return) from
    squashing the rest: Tukey's fences, `fence` interquartile ranges (at least 1 unit) beyond
    the quartiles, padded; None when every value lies within them."""
    if len(values) < 4:
        return None
    q1, q3 = np.percentile(values, [25, 75])
    spread = max(float(q3 - q1), 1.0)
    inside = [v for v in values if q1 - fence * spread <= v <= q3 + fence * spread]
    if len(inside) == len(values):
        return None
    pad = 0.1 * max(max(inside) - min(inside), 1.0)
    return min(inside) - pad, max(inside) + pad


def _clip_outliers(ax: Axes, xs: Sequence[float], values: Sequence[float]) -> str:
    """Clips the y-axis to robust_limits and draws each value beyond it as a triangle at the
    edge with its value beside; returns what the title should say about it."""
    limits = robust_limits(values)
    if limits is None:
        return ""
    lo, hi = limits
    ax.set_ylim(lo, hi)
    beyond = [(x, v) for x, v in zip(xs, values, strict=True) if not lo <= v <= hi]
    for x, v in beyond:
        edge, marker, va = (lo, "v", "bottom") if v < lo else (hi, "^", "top")
        ax.plot([x], [edge], marker=marker, color="#d62728", ms=7, clip_on=False, zorder=4)
        ax.annotate(
            f"{v:.0f}",
            (x, edge),
            xytext=(7, 2),
            textcoords="offset points",
            fontsize=7,
            color="#d62728",
            va=va,
        )
    some = f"{len(beyond)} episodes" if len(beyond) > 1 else "1 episode"
    return (
        f"; y-axis clipped to {lo:.0f} to {hi:.0f}: {some} beyond it, each drawn at the edge "
        "with its value"
    )


def _mark_runs(axes: Sequence[Axes], at: Sequence[float]) -> None:
    """A dashed line where the simulator restarted (a new run of the log)."""
    for x in at:
        for ax in axes:
            ax.axvline(x, color="#7f7f7f", ls="--", lw=0.8)
        axes[0].annotate(
            "simulator restarted",
            (x, 1.0),
            xycoords=("data", "axes fraction"),
            xytext=(3, -10),
            textcoords="offset points",
            fontsize=7,
        )


def draw_learning(robot: RobotSummary, path: Path, counts: EpisodeCounts | None = None) -> None:
    """Episode returns (with their moving average), steps and interventions, one panel each,
    marking where the robot converged and where the simulator restarted."""
    ended = robot.ended
    x = [e.position for e in ended]
    fig, axes = plt.subplots(3, 1, figsize=(7.5, 7), dpi=100, sharex=True)
    try:
        _draw_returns(axes[0], robot.robot, ended, x)
        axes[1].plot(x, [e.steps for e in ended], ".-", color="#1f77b4", lw=0.8, ms=4)
        axes[1].set_ylim(bottom=0)
        axes[1].set_ylabel(f"steps\n({STEP_SECONDS:g} robot s each)")
        _draw_interventions(axes[2], ended, x)
        if counts is not None and counts.convergence.converged_at is not None:
            _mark_convergence(axes, x[counts.convergence.converged_at], counts)
        _mark_runs(axes, [position - 0.5 for _, position in robot.restarts])
        if robot.restarts:
            axes[2].set_xlabel("episode, in the order they happened (the runs one after another)")
        else:
            axes[2].set_xlabel("episode")
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)


def _draw_returns(
    ax: Axes, robot: str, ended: Sequence[EpisodeSummary], x: Sequence[float]
) -> None:
    """Each episode's return, coloured by how it ended, and their moving average."""
    returns = [e.env_return for e in ended]
    colors = [{"goal": "#2ca02c", "collision": "#d62728"}.get(e.outcome, "#7f7f7f") for e in ended]
    ax.scatter(x, returns, c=colors, s=12)
    if ended:
        ax.plot(
            x,
            moving_average(returns),
            color="black",
            lw=1.2,
            label=f"mean of the last {MOVING_AVERAGE}",
        )
        ax.legend(fontsize=7, loc="lower right")
    clipped = _clip_outliers(ax, x, returns)
    ax.set_ylabel("return R_RL\n(reward units)")
    ax.set_title(
        f"robot {robot}: {len(ended)} episodes (green goal, red collision, grey timeout){clipped}",
        fontsize=9,
        wrap=True,
    )


def _draw_interventions(ax: Axes, ended: Sequence[EpisodeSummary], x: Sequence[float]) -> None:
    """Each episode's interventions, pale where the count is not the arbiter's final one."""
    interventions = [e.interventions for e in ended]
    final = [e.final for e in ended]
    ax.bar(x, interventions, color=["#9467bd" if f else "#c5b0d5" for f in final])
    ax.set_ylim(0, max([*interventions, 1]) * 1.15)
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    if not any(interventions):
        ax.text(0.5, 0.5, "no interventions", transform=ax.transAxes, ha="center")
    elif not all(final):
        ax.text(
            0.01,
            0.92,
            "pale: not the arbiter's final count",
            transform=ax.transAxes,
            fontsize=7,
            va="top",
        )
    ax.set_ylabel("interventions\n(understood utterances)")


def _mark_convergence(axes: Sequence[Axes], at: float, counts: EpisodeCounts) -> None:
    """A green line through every panel at the episode that converged."""
    for ax in axes:
        ax.axvline(at, color="#2ca02c", lw=0.8, alpha=0.7)
    axes[1].annotate(
        f"converged (episode {counts.converged_at})",
        (at, 1.0),
        xycoords=("data", "axes fraction"),
        xytext=(3, -10),
        textcoords="offset points",
        fontsize=7,
    )


def draw_rewards(robot: RobotSummary, path: Path) -> None:
    """The environment's return within each episode; the teacher's words at their value when
    they arrived; the reward each step was credited with; when things were heard."""
    fig, axes = plt.subplots(
        4, 1, figsize=(9.5, 9), dpi=100, sharex=True, height_ratios=(3, 2.2, 2.2, 1.2)
    )
    try:
        axes[0].plot(np.asarray(robot.steps), _returns_so_far(robot), color="#7f7f7f", lw=0.8)
        axes[0].set_ylabel("return so far in\nthe episode (R_RL)")
        axes[0].set_title(
            f"robot {robot.robot}: rewards over the steps (reward units: the vocabulary's, "
            "e.g. good +10)",
            fontsize=10,
        )
        _draw_words(axes[1], robot)
        _draw_credits(axes[2], robot)
        _draw_arrivals(axes[3], robot)
        _mark_runs(axes, [step - 0.5 for step, _ in robot.restarts])
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)


def _returns_so_far(robot: RobotSummary) -> np.ndarray:
    """At each observed step, the sum of the rewards of its episode up to it."""
    within = np.zeros(len(robot.steps))
    total, current = 0.0, None
    for i, (reward, episode) in enumerate(zip(robot.rewards, robot.episode_of_step, strict=True)):
        if episode != current:
            total, current = 0.0, episode
        total += reward
        within[i] = total
    return within


def _draw_words(ax: Axes, robot: RobotSummary) -> None:
    """The teacher's words at their value: what each feedback message gave, in all."""
    if robot.words:
        s, v, _ = zip(*robot.words, strict=True)
        colors = ["#2ca02c" if r > 0 else "#d62728" for r in v]
        ax.vlines(s, 0, v, colors=colors, lw=0.8)
        ax.scatter(s, v, c=colors, s=14, zorder=3)
    else:
        ax.text(0.5, 0.5, "no teacher reward", transform=ax.transAxes, ha="center")
    ax.axhline(0, color="#bbbbbb", lw=0.6)
    ax.set_ylabel("teacher's word R_T\n(at arrival)")


def _draw_credits(ax: Axes, robot: RobotSummary) -> None:
    """Each word's reward split over the steps it is about (the shares sum to the word)."""
    if robot.credits:
        s, v = zip(*robot.credits, strict=True)
        colors = ["#2ca02c" if r > 0 else "#d62728" for r in v]
        ax.scatter(s, v, c=colors, s=8, zorder=3)
    else:
        ax.text(0.5, 0.5, "nothing credited", transform=ax.transAxes, ha="center")
    ax.axhline(0, color="#bbbbbb", lw=0.6)
    ax.set_ylabel("credited to the step\n(word's R_T x share)")


def _draw_arrivals(ax: Axes, robot: RobotSummary) -> None:
    """When things arrived: one row each, no values."""
    rows = (
        ("utterance heard", [s for s, _ in robot.utterances], "d", "#17becf"),
        ("reward arrives", [s for s, _, _ in robot.words], "v", "#9467bd"),
        ("command arrives", [s for s, _ in robot.commands], "s", "#ff7f0e"),
    )
    for row, (_, at, marker, color) in enumerate(rows):
        ax.scatter(at, [row] * len(at), marker=marker, color=color, s=14)
    ax.set_yticks(range(len(rows)), [name for name, *_ in rows], fontsize=7)
    ax.set_ylim(-0.6, len(rows) - 0.4)
    ax.set_xlabel("step (continued across restarts of the simulator)" if robot.restarts else "step")

"""`voxshape report RUN_DIR`: pictures and a short summary of a session, without a viewer.

Reads the event log (the session's one record) and writes into RUN_DIR/report/:

    trajectories-<robot>.png   the map, y-up, with the paths of a few episodes
    learning-<robot>.png       episode returns (and their moving average), steps, interventions
    rewards-<robot>.png        return within each episode over the steps; the teacher's words
                               at their value; the reward credited to each step; when
                               utterances, feedback and commands arrived
    summary.md                 the numbers, and the pictures

Episodes and interventions are counted one way for every file of a run (`count_episodes`, which
the demo's demo.md uses too): interventions are the utterances the arbiter understood about an
episode, its own count (TeachingStats, as in the paper's Table 3), and convergence is judged by
the map the session ran on. A simulator that restarted within one log (its episode numbers and
steps start again at 0) starts a new run: episodes are kept in the order they happened, never
merged by number.

`summarize` and `count_episodes` are pure (records in, numbers out); the drawing is matplotlib,
headless.
"""

from __future__ import annotations

import argparse
import math
import statistics
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: no display needed
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.patches import Circle, FancyArrow, Polygon
from matplotlib.ticker import MaxNLocator

from protocol import (
    Action,
    CreditedFeedback,
    EpisodeEvent,
    LearningSummary,
    Observation,
    TeachingStats,
    Utterance,
)
from services.learner.config import LearnerConfig
from services.learner.convergence import Convergence, EpisodeResult, convergence_on
from services.logger.decoding import Known, PresenceChange, Rejected, Unknown, decode_record
from services.logger.eventlog import EventLog, EventLogError, EventRecord, read_events
from services.logger.run import RunDir, RunError, read_session_info, session_map
from services.world.maps import Box, Cylinder, Map
from services.world.robot import CONTROL_PERIOD_S

MAX_EPISODES_DRAWN = 6
MOVING_AVERAGE = 10
STEP_SECONDS = CONTROL_PERIOD_S  # robot seconds per step
INTERVENTIONS_ARE = (
    "interventions are the utterances the arbiter understood about an episode, its own count "
    "(TeachingStats), as in the paper's Table 3"
)


@dataclass
class EpisodeSummary:
    number: int  # the simulator's; it starts again at 0 when the simulator restarts
    run: int = 0  # which start of the simulator in this log it belongs to (0: the first)
    position: int = 0  # in the order episodes happened: its number after the earlier runs'
    outcome: str = "running"  # goal, collision, timeout, or running (no end seen)
    steps: int = 0
    env_return: float = 0.0
    interventions: int = 0  # understood utterances about it, the arbiter's count
    final: bool = False  # `interventions` is the arbiter's final count (sent once settled)
    xs: list[float] = field(default_factory=list)
    ys: list[float] = field(default_factory=list)
    first_step: int | None = None
    last_step: int | None = None

    @property
    def seconds(self) -> float:
        """Robot seconds it took (so far, if it is still running)."""
        return (self.steps or len(self.xs)) * STEP_SECONDS


@dataclass
class RobotSummary:
    """One robot's episodes and steps in the order they happened. Its steps are continued
    across restarts of the simulator (a run's steps follow the last one's), so pictures never
    draw two runs over each other."""

    robot: str
    episodes: list[EpisodeSummary] = field(default_factory=list)  # in the order they happened
    restarts: list[tuple[int, int]] = field(default_factory=list)  # (step, position) of each
    # run after the first
    steps: list[int] = field(default_factory=list)  # every observed step, continued
    rewards: list[float] = field(default_factory=list)  # R_RL of each observed step
    episode_of_step: list[int] = field(default_factory=list)  # its episode's position
    credits: list[tuple[int, float]] = field(default_factory=list)  # (credited step, reward x
    # share): what each step was given of a teacher's word
    words: list[tuple[int, float, str]] = field(default_factory=list)  # (arrival step, reward,
    # who): each reward feedback at its value
    commands: list[tuple[int, str]] = field(default_factory=list)  # (arrival step, command)
    utterances: list[tuple[int, str]] = field(default_factory=list)  # (arrival step, what)
    actions: dict[str, int] = field(default_factory=lambda: {"policy": 0, "teacher": 0})
    states: int = 0
    _current: dict[int, EpisodeSummary] = field(default_factory=dict, repr=False)  # this run's
    _started: set[int] = field(default_factory=set, repr=False)  # this run's begun episodes
    _last_step: int | None = field(default=None, repr=False)  # the simulator's, this run
    _observed: int | None = field(default=None, repr=False)  # the latest observed step, this run
    _step_offset: int = field(default=0, repr=False)
    _episode_offset: int = field(default=0, repr=False)

    @property
    def runs(self) -> int:
        """How many times the simulator started in the log."""
        return len(self.restarts) + 1

    @property
    def ended(self) -> list[EpisodeSummary]:
        return [e for e in self.episodes if e.outcome != "running"]

    @property
    def here(self) -> int | None:
        """The latest observed step, continued across runs (None before any)."""
        return None if self._observed is None else self._observed + self._step_offset

    def label(self, e: EpisodeSummary) -> str:
        """How the report names an episode: its number, or run:number once the simulator
        restarted within the log."""
        return str(e.number) if not self.restarts else f"{e.run + 1}:{e.number}"

    def episode(self, number: int) -> EpisodeSummary:
        """Episode `number` of the current run."""
        if number not in self._current:
            e = EpisodeSummary(number, self.runs - 1, number + self._episode_offset)
            self._current[number] = e
            self.episodes.append(e)
        return self._current[number]

    def follow(self, step: int, episode: int, starts: bool = False) -> None:
        """Starts a new run when the simulator restarted: its step or episode number went
        back, or an episode it already began begins again."""
        last = self._last_step
        if last is not None and (
            step < last
            or episode < max(self._current, default=episode)
            or (starts and episode in self._started)
        ):
            self._step_offset += last + 1
            self._episode_offset = max(e.position for e in self.episodes) + 1
            self.restarts.append((self._step_offset, self._episode_offset))
            self._current, self._started, self._observed, last = {}, set(), None, None
        self._last_step = step if last is None else max(last, step)
        if starts:
            self._started.add(episode)

    def observe(self, obs: Observation) -> None:
        self.follow(obs.step, obs.episode)
        self._observed = obs.step
        e = self.episode(obs.episode)
        self.steps.append(obs.step + self._step_offset)
        self.rewards.append(obs.reward)
        self.episode_of_step.append(e.position)
        e.xs.append(obs.x)
        e.ys.append(obs.y)
        e.first_step = obs.step if e.first_step is None else e.first_step
        e.last_step = obs.step

    def on_episode(self, event: EpisodeEvent) -> None:
        self.follow(event.step, event.episode, starts=event.kind == "start")
        e = self.episode(event.episode)
        if event.kind != "start":
            e.outcome, e.steps, e.env_return = event.kind, event.episode_steps, event.env_return

    def on_teaching(self, stats: TeachingStats) -> None:
        """The arbiter's count for an episode: this run's of that number, else the latest
        earlier run's (its final counts come a few seconds after the episode ended)."""
        e = self._current.get(stats.episode) or next(
            (e for e in reversed(self.episodes) if e.number == stats.episode), None
        )
        if e is not None and (stats.final or not e.final):
            e.interventions, e.final = stats.interventions, stats.final

    def on_feedback(self, fb: CreditedFeedback) -> None:
        here, who = self.here, ", ".join(fb.teachers)
        if fb.kind == "reward":
            self.credits += [(c.step + self._step_offset, fb.reward * c.weight) for c in fb.credits]
            if here is not None:
                self.words.append((here, fb.reward, who))
        elif here is not None:
            self.commands.append((here, f"{who}: {fb.command}"))

    def find(self, label: str) -> EpisodeSummary:
        """The episode named `label`: a number, or run:number once the simulator restarted."""
        run_text, _, number_text = label.rpartition(":")
        try:
            number, run = int(number_text), (int(run_text) - 1 if run_text else None)
        except ValueError:
            raise RunError(f"episode {label!r} is not a number (nor run:number)") from None
        found = [e for e in self.episodes if e.number == number and run in (None, e.run)]
        if len(found) == 1:
            return found[0]
        if found:
            runs = " and ".join(str(e.run + 1) for e in found)
            raise RunError(
                f"robot {self.robot} has an episode {number} in runs {runs} (the simulator "
                f"restarted): say which, e.g. {found[-1].run + 1}:{number}"
            )
        if not self.episodes:
            raise RunError(f"robot {self.robot} has no episodes")
        raise RunError(f"robot {self.robot} has no episode {label} (it has {self.span()})")

    def span(self) -> str:
        """The episodes it has: 0-41, or 1:0-1:13, 2:0-2:5 across runs."""
        spans = []
        for run in range(self.runs):
            mine = [e for e in self.episodes if e.run == run]
            if mine:
                first, last = self.label(mine[0]), self.label(mine[-1])
                spans.append(first if first == last else f"{first}-{last}")
        return ", ".join(spans)


@dataclass
class SessionSummary:
    session: str
    robots: dict[str, RobotSummary] = field(default_factory=dict)
    records: int = 0
    rejected: int = 0
    unknown_types: int = 0
    nodes: set[str] = field(default_factory=set)
    first_wall: float | None = None
    last_wall: float | None = None

    def robot(self, name: str) -> RobotSummary:
        if name not in self.robots:
            self.robots[name] = RobotSummary(name)
        return self.robots[name]


def summarize(records: Iterable[EventRecord], session: str = "") -> SessionSummary:
    """The session's numbers from its event-log records."""
    summary = SessionSummary(session)
    for record in records:
        decoded = decode_record(record)
        summary.records += 1
        summary.first_wall = summary.first_wall or record.received
        summary.last_wall = record.received
        match decoded:
            case Known(message=Observation() as obs):
                summary.robot(obs.robot).observe(obs)
            case Known(message=EpisodeEvent() as event):
                summary.robot(event.robot).on_episode(event)
            case Known(message=TeachingStats() as stats):
                summary.robot(stats.robot).on_teaching(stats)
            case Known(message=CreditedFeedback() as fb):
                summary.robot(fb.robot).on_feedback(fb)
            case Known(message=Utterance() as u):
                r = summary.robot(u.robot)
                if r.here is not None:
                    r.utterances.append((r.here, f"{u.teacher}: {u.text!r}"))
            case Known(message=Action() as action):
                summary.robot(action.robot).actions[action.chooser] += 1
            case Known(message=LearningSummary() as learning):
                summary.robot(learning.robot).states = learning.states
            case PresenceChange(role=role, node=node):
                summary.nodes.add(f"{role} {node}")
            case Unknown():
                summary.unknown_types += 1
            case Rejected():
                summary.rejected += 1
    return summary


# -- counting ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class EpisodeCounts:
    """A robot's episodes and interventions as every file of a run states them (summary.md,
    the demo's demo.md): to convergence, and all that the log holds."""

    convergence: Convergence  # over the ended episodes, in the order they happened
    converged_at: str | None  # the label of the episode that converged
    ended: int  # episodes ended in the log
    interventions: int  # about the ended episodes
    unfinished: int  # episodes still running when the log ends (or cut by a restart)
    unfinished_interventions: int  # about those
    provisional: int  # ended episodes whose count is not the arbiter's final one

    def describe(self) -> str:
        """The counts in two sentences: to convergence, then all that was recorded."""
        c = self.convergence
        if c.converged:
            head = (
                f"The robot converged after {c.n_episodes} episodes ({c.learning_time / 60:.1f} "
                f"robot minutes, at episode {self.converged_at}). To convergence: "
                f"{c.n_episodes} episodes, {c.interventions} interventions"
            )
        else:
            head = f"The robot did not converge within the {self.ended} episodes recorded"
        tail = f"recorded in all: {self.ended} episodes ended, {self.interventions} interventions"
        if self.unfinished:
            tail += (
                f", and {self.unfinished} unfinished episode{'s' if self.unfinished > 1 else ''} "
                f"({self.unfinished_interventions} interventions so far)"
            )
        text = f"{head}; {tail}."
        if self.provisional:
            text += (
                f" {self.provisional} of the ended episodes lack the arbiter's final count: the "
                "session stopped before it settled."
            )
        return text


def count_episodes(
    robot: RobotSummary, m: Map, config: LearnerConfig | None = None
) -> EpisodeCounts:
    """Episodes and interventions to convergence (judged by map `m`'s shortest time, the
    learner's rule) and in all; the one count every file of a run states."""
    convergence = convergence_on(m, config or LearnerConfig())
    ended = robot.ended
    for e in ended:
        convergence.add(EpisodeResult(e.outcome, e.steps, e.seconds, e.interventions))
    running = [e for e in robot.episodes if e.outcome == "running"]
    at = convergence.converged_at
    return EpisodeCounts(
        convergence=convergence,
        converged_at=None if at is None else robot.label(ended[at]),
        ended=len(ended),
        interventions=sum(e.interventions for e in ended),
        unfinished=len(running),
        unfinished_interventions=sum(e.interventions for e in running),
        provisional=sum(not e.final for e in ended),
    )


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


# -- summary -----------------------------------------------------------------------------------


def markdown(
    summary: SessionSummary,
    m: Map,
    pictures: dict[str, list[Path]],
    counts: dict[str, EpisodeCounts] | None = None,
) -> str:
    counts = counts or {name: count_episodes(r, m) for name, r in summary.robots.items()}
    lines = [f"# Session {summary.session}", ""]
    duration = (summary.last_wall or 0) - (summary.first_wall or 0)
    lines += [
        f"- map: {m.name}",
        f"- {summary.records} messages over {duration:.1f} s of wall time; "
        f"{summary.rejected} rejected, {summary.unknown_types} of unknown types",
        f"- nodes seen: {', '.join(sorted(summary.nodes)) or 'none'}",
        "",
    ]
    for name, r in sorted(summary.robots.items()):
        ended = r.ended
        outcomes = {k: sum(e.outcome == k for e in ended) for k in ("goal", "collision", "timeout")}
        last = ended[-MOVING_AVERAGE:]
        best = max(ended, key=lambda e: e.env_return) if ended else None
        count = counts[name]
        lines += [f"## Robot {name}", ""]
        if r.restarts:
            lines += [
                f"The simulator started {r.runs} times in this log (its episode numbers start "
                "again at 0): episodes are named run:number and kept in the order they "
                f"happened ({r.span()}).",
                "",
            ]
        lines += [
            count.describe(),
            "",
            f"Convergence: {count.convergence.rule()}; {INTERVENTIONS_ARE}.",
            "",
            "| | |",
            "|---|---|",
            f"| steps observed | {len(r.steps)} |",
            f"| episodes ended | {len(ended)}: {outcomes['goal']} goal, "
            f"{outcomes['collision']} collision, {outcomes['timeout']} timeout |",
            f"| mean return, last {len(last)} | "
            f"{statistics.fmean(e.env_return for e in last):+.1f} |"
            if last
            else "| mean return | - |",
            f"| best return | {best.env_return:+.1f} (episode {r.label(best)}, {best.steps} "
            "steps) |"
            if best
            else "| best return | - |",
            f"| actions by policy / teacher | {r.actions['policy']} / {r.actions['teacher']} |",
            f"| feedback messages (reward / command) / utterances heard | {len(r.words)} / "
            f"{len(r.commands)} / {len(r.utterances)} |",
            f"| states at the end | {r.states} |",
            "",
        ]
        for picture in pictures.get(name, []):
            lines.append(f"![{picture.stem}]({picture.name})")
        lines.append("")
    return "\n".join(lines)


@dataclass
class LoadedRun:
    """A run's event log summed up, with the map it ran on."""

    summary: SessionSummary
    map: Map
    log: EventLog

    def counts(self, config: LearnerConfig | None = None) -> dict[str, EpisodeCounts]:
        return {n: count_episodes(r, self.map, config) for n, r in self.summary.robots.items()}


def load_run(run: RunDir, task: str | None = None) -> LoadedRun:
    """Reads a run's event log and map (`task`, else the one in session.json)."""
    try:
        log = read_events(run.events)
    except EventLogError as e:
        raise RunError(str(e)) from None
    m = session_map(run, task)
    try:
        session = read_session_info(run).session
    except RunError:
        session = log.header.session
    return LoadedRun(summarize(log.records, session), m, log)


def write_report(
    run: RunDir,
    task: str | None = None,
    episodes: Sequence[str] | None = None,
    loaded: LoadedRun | None = None,
) -> list[Path]:
    """Writes the pictures and summary.md into run/report/; returns their paths."""
    loaded = loaded or load_run(run, task)
    summary, m = loaded.summary, loaded.map
    counts = loaded.counts()
    out = run.report
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    pictures: dict[str, list[Path]] = {}
    for name, robot in sorted(summary.robots.items()):
        paths = [
            out / f"trajectories-{name}.png",
            out / f"learning-{name}.png",
            out / f"rewards-{name}.png",
        ]
        draw_trajectories(m, pick_episodes(robot, episodes), robot, paths[0])
        draw_learning(robot, paths[1], counts[name])
        draw_rewards(robot, paths[2])
        pictures[name] = paths
        written += paths
    text = markdown(summary, m, pictures, counts)
    if loaded.log.describe_tail():
        text += f"\nNote: {loaded.log.describe_tail()}.\n"
    (out / "summary.md").write_text(text, encoding="utf-8")
    written.append(out / "summary.md")
    return written


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="the run directory, e.g. runs/<session>")
    parser.add_argument("--task", help="draw this map (default: the one in RUN/session.json)")
    parser.add_argument(
        "--episodes",
        type=lambda text: [n.strip() for n in text.split(",") if n.strip()],
        help="episodes to draw, e.g. 0,10,42, or run:number (2:0) when the simulator restarted "
        "within the log (default: first, best, middle, last)",
    )


def run(args: argparse.Namespace) -> int:
    run_dir = RunDir.existing(args.run)
    for path in write_report(run_dir, args.task, args.episodes):
        print(path)
    return 0

"""`voxshape report RUN_DIR`: pictures and a short summary of a session, without a viewer.

Reads the event log (the session's one record) and writes into RUN_DIR/report/:

    trajectories-<robot>.png   the map, y-up, with the paths of a few episodes
    learning-<robot>.png       episode returns (and their moving average), steps, interventions
    rewards-<robot>.png        return within each episode over the steps; teacher rewards at
                               the steps they were credited to; feedback and utterances
    summary.md                 the numbers, and the pictures

`summarize` is pure (records in, numbers out); the drawing is matplotlib, headless.
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

from protocol import (
    Action,
    CreditedFeedback,
    EpisodeEvent,
    LearningSummary,
    Observation,
    Utterance,
)
from services.logger.decoding import Known, PresenceChange, Rejected, Unknown, decode_record
from services.logger.eventlog import EventLogError, EventRecord, read_events
from services.logger.run import RunDir, RunError, read_session_info, session_map
from services.logger.tally import SessionTally
from services.sim.maps import Box, Cylinder, Map

MAX_EPISODES_DRAWN = 6
MOVING_AVERAGE = 10


@dataclass
class EpisodeSummary:
    number: int
    outcome: str = "running"  # goal, collision, timeout, or running (no end seen)
    steps: int = 0
    env_return: float = 0.0
    interventions: int = 0
    xs: list[float] = field(default_factory=list)
    ys: list[float] = field(default_factory=list)
    first_step: int | None = None
    last_step: int | None = None


@dataclass
class RobotSummary:
    robot: str
    episodes: dict[int, EpisodeSummary] = field(default_factory=dict)
    steps: list[int] = field(default_factory=list)  # every observed step
    rewards: list[float] = field(default_factory=list)  # R_RL of each observed step
    episode_of_step: list[int] = field(default_factory=list)
    teacher_rewards: list[tuple[int, float]] = field(default_factory=list)  # credited step
    feedback: list[tuple[int | None, str]] = field(default_factory=list)  # arrival step, what
    utterances: list[tuple[int | None, str]] = field(default_factory=list)
    actions: dict[str, int] = field(default_factory=lambda: {"policy": 0, "teacher": 0})
    states: int = 0

    def episode(self, number: int) -> EpisodeSummary:
        if number not in self.episodes:
            self.episodes[number] = EpisodeSummary(number)
        return self.episodes[number]

    @property
    def ended(self) -> list[EpisodeSummary]:
        return [e for e in self.episodes.values() if e.outcome != "running"]


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
    tally = SessionTally()
    for record in records:
        decoded = decode_record(record)
        tally.observe(decoded)
        summary.records += 1
        summary.first_wall = summary.first_wall or record.received
        summary.last_wall = record.received
        match decoded:
            case Known(message=Observation() as obs):
                r = summary.robot(obs.robot)
                r.steps.append(obs.step)
                r.rewards.append(obs.reward)
                r.episode_of_step.append(obs.episode)
                e = r.episode(obs.episode)
                e.xs.append(obs.x)
                e.ys.append(obs.y)
                e.first_step = obs.step if e.first_step is None else e.first_step
                e.last_step = obs.step
            case Known(message=EpisodeEvent() as event) if event.kind != "start":
                e = summary.robot(event.robot).episode(event.episode)
                e.outcome, e.steps, e.env_return = event.kind, event.episode_steps, event.env_return
                e.interventions = tally.robot(event.robot).interventions
            case Known(message=CreditedFeedback() as fb):
                r = summary.robot(fb.robot)
                who = ", ".join(fb.teachers)
                if fb.kind == "reward":
                    r.teacher_rewards += [(c.step, fb.reward * c.weight) for c in fb.credits]
                    r.feedback.append((tally.robot(fb.robot).step, f"{who}: {fb.reward:+g}"))
                else:
                    r.feedback.append((tally.robot(fb.robot).step, f"{who}: {fb.command}"))
            case Known(message=Utterance() as u):
                summary.robot(u.robot).utterances.append(
                    (tally.robot(u.robot).step, f"{u.teacher}: {u.text!r}")
                )
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


def pick_episodes(robot: RobotSummary, wanted: Sequence[int] | None = None) -> list[EpisodeSummary]:
    """The episodes to draw: those asked for, else the first, the best, a middle one and the
    last that ended (at most MAX_EPISODES_DRAWN)."""
    if wanted:
        missing = [n for n in wanted if n not in robot.episodes]
        if missing:
            known = sorted(robot.episodes)
            raise RunError(
                f"robot {robot.robot} has no episode {missing[0]} (it has {known[0]}-{known[-1]})"
                if known
                else f"robot {robot.robot} has no episodes"
            )
        return [robot.episodes[n] for n in wanted][:MAX_EPISODES_DRAWN]
    ended = sorted(robot.ended, key=lambda e: e.number) or sorted(
        robot.episodes.values(), key=lambda e: e.number
    )
    if not ended:
        return []
    best = max(ended, key=lambda e: (e.env_return, -e.number))
    chosen = {ended[0].number, best.number, ended[len(ended) // 2].number, ended[-1].number}
    return [robot.episodes[n] for n in sorted(chosen)]


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


def draw_trajectories(m: Map, episodes: Sequence[EpisodeSummary], robot: str, path: Path) -> None:
    scale = 6.0 / max(m.width, m.height)
    fig, ax = plt.subplots(figsize=(m.width * scale + 2.6, m.height * scale + 0.6), dpi=100)
    try:
        draw_map(ax, m)
        colors = plt.get_cmap("viridis")(np.linspace(0, 0.9, max(1, len(episodes))))
        for e, color in zip(episodes, colors, strict=False):
            label = f"ep {e.number}: {e.outcome}, {e.steps or len(e.xs)} steps"
            ax.plot(e.xs, e.ys, color=color, lw=1.4, label=label)
            if e.xs:
                ax.plot(e.xs[-1], e.ys[-1], "o", color=color, ms=4)
        ax.set_title(f"{m.name}: robot {robot}", fontsize=10)
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


def draw_learning(robot: RobotSummary, path: Path) -> None:
    ended = sorted(robot.ended, key=lambda e: e.number)
    numbers = [e.number for e in ended]
    fig, axes = plt.subplots(3, 1, figsize=(7, 6.5), dpi=100, sharex=True)
    try:
        returns = [e.env_return for e in ended]
        colors = [
            {"goal": "#2ca02c", "collision": "#d62728"}.get(e.outcome, "#7f7f7f") for e in ended
        ]
        axes[0].scatter(numbers, returns, c=colors, s=12)
        if ended:
            axes[0].plot(
                numbers,
                moving_average(returns),
                color="black",
                lw=1.2,
                label=f"mean of last {MOVING_AVERAGE}",
            )
            axes[0].legend(fontsize=7)
        axes[0].set_ylabel("return (R_RL)")
        axes[0].set_title(
            f"robot {robot.robot}: {len(ended)} episodes (green goal, red collision, grey timeout)",
            fontsize=10,
        )
        axes[1].plot(numbers, [e.steps for e in ended], ".-", color="#1f77b4", lw=0.8, ms=4)
        axes[1].set_ylabel("steps")
        interventions = [e.interventions for e in ended]
        axes[2].bar(numbers, interventions, color="#9467bd")
        axes[2].set_ylim(0, max([*interventions, 1]) * 1.1)
        if not any(interventions):
            axes[2].text(0.5, 0.5, "no interventions", transform=axes[2].transAxes, ha="center")
        axes[2].set_ylabel("interventions")
        axes[2].set_xlabel("episode")
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)


def draw_rewards(robot: RobotSummary, path: Path) -> None:
    fig, axes = plt.subplots(2, 1, figsize=(9, 5.5), dpi=100, sharex=True)
    try:
        steps = np.asarray(robot.steps)
        within = np.zeros(len(steps))
        total, current = 0.0, None
        for i, (reward, episode) in enumerate(
            zip(robot.rewards, robot.episode_of_step, strict=True)
        ):
            if episode != current:
                total, current = 0.0, episode
            total += reward
            within[i] = total
        axes[0].plot(steps, within, color="#7f7f7f", lw=0.8)
        axes[0].set_ylabel("return so far\nin the episode")
        axes[0].set_title(f"robot {robot.robot}: rewards over the steps", fontsize=10)
        if robot.teacher_rewards:
            s, v = zip(*robot.teacher_rewards, strict=True)
            axes[1].scatter(
                s, v, color="#d62728", s=14, label="teacher reward (credited step)", zorder=3
            )
        arrivals = [step for step, _ in robot.feedback if step is not None]
        if arrivals:
            axes[1].scatter(
                arrivals,
                np.zeros(len(arrivals)),
                marker="v",
                color="#9467bd",
                s=18,
                label="feedback arrives",
                zorder=2,
            )
        heard = [step for step, _ in robot.utterances if step is not None]
        if heard:
            axes[1].scatter(
                heard,
                np.zeros(len(heard)) - 2,
                marker="d",
                color="#17becf",
                s=14,
                label="utterance",
                zorder=2,
            )
        axes[1].axhline(0, color="#bbbbbb", lw=0.6)
        axes[1].set_ylabel("teacher")
        axes[1].set_xlabel("step")
        if robot.teacher_rewards or arrivals or heard:
            axes[1].legend(fontsize=7, loc="upper left")
        else:
            axes[1].text(0.5, 0.5, "no teacher spoke", transform=axes[1].transAxes, ha="center")
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)


# -- summary -----------------------------------------------------------------------------------


def markdown(summary: SessionSummary, m: Map, pictures: dict[str, list[Path]]) -> str:
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
        ended = sorted(r.ended, key=lambda e: e.number)
        outcomes = {k: sum(e.outcome == k for e in ended) for k in ("goal", "collision", "timeout")}
        last = ended[-MOVING_AVERAGE:]
        best = max(ended, key=lambda e: e.env_return) if ended else None
        lines += [
            f"## Robot {name}",
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
            f"| best return | {best.env_return:+.1f} (episode {best.number}, {best.steps} steps) |"
            if best
            else "| best return | - |",
            f"| actions by policy / teacher | {r.actions['policy']} / {r.actions['teacher']} |",
            f"| feedback / utterances | {len(r.feedback)} / {len(r.utterances)} |",
            f"| interventions (all episodes) | {sum(e.interventions for e in ended)} |",
            f"| states at the end | {r.states} |",
            "",
        ]
        for picture in pictures.get(name, []):
            lines.append(f"![{picture.stem}]({picture.name})")
        lines.append("")
    return "\n".join(lines)


def write_report(
    run: RunDir, task: str | None = None, episodes: Sequence[int] | None = None
) -> list[Path]:
    """Writes the pictures and summary.md into run/report/; returns their paths."""
    try:
        log = read_events(run.events)
    except EventLogError as e:
        raise RunError(str(e)) from None
    m = session_map(run, task)
    try:
        session = read_session_info(run).session
    except RunError:
        session = log.header.session
    summary = summarize(log.records, session)
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
        draw_trajectories(m, pick_episodes(robot, episodes), name, paths[0])
        draw_learning(robot, paths[1])
        draw_rewards(robot, paths[2])
        pictures[name] = paths
        written += paths
    text = markdown(summary, m, pictures)
    if log.describe_tail():
        text += f"\nNote: {log.describe_tail()}.\n"
    (out / "summary.md").write_text(text, encoding="utf-8")
    written.append(out / "summary.md")
    return written


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="the run directory, e.g. runs/<session>")
    parser.add_argument("--task", help="draw this map (default: the one in RUN/session.json)")
    parser.add_argument(
        "--episodes",
        type=lambda text: [int(n) for n in text.split(",") if n],
        help="episodes to draw, e.g. 0,10,42 (default: first, best, middle, last)",
    )


def run(args: argparse.Namespace) -> int:
    run_dir = RunDir.existing(args.run)
    for path in write_report(run_dir, args.task, args.episodes):
        print(path)
    return 0

"""`voxshape report RUN_DIR`: reads a run's event log and map, and writes its pictures and
summary.md into RUN_DIR/report/."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from voxshape.lab.report.counts import EpisodeCounts, count_episodes
from voxshape.lab.report.pictures import (
    draw_learning,
    draw_rewards,
    draw_trajectories,
    pick_episodes,
)
from voxshape.lab.report.summary import SessionSummary, summarize_session
from voxshape.lab.report.summary_md import summary_markdown
from voxshape.runtime.settings_file import read_settings
from voxshape.services.learner.config import LearnerConfig
from voxshape.services.logger.eventlog import EventLog, EventLogError, read_events
from voxshape.services.logger.run import RunDir, RunError, read_session_info, session_map
from voxshape.world.maps import Map


@dataclass
class LoadedRun:
    """A run's event log summed up, with the map it ran on."""

    summary: SessionSummary
    map: Map
    log: EventLog
    learner: LearnerConfig  # the settings the run's learner recorded (learning_settings)

    def counts(self) -> dict[str, EpisodeCounts]:
        """Each robot's, judged by the run's map and its learner's settings."""
        return {
            n: count_episodes(r, self.map, self.learner) for n, r in self.summary.robots.items()
        }


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
    return LoadedRun(summarize_session(log.records, session), m, log, learning_settings(run))


def learning_settings(run: RunDir) -> LearnerConfig:
    """The settings the run's learner recorded in its settings.json; a run made before
    learners recorded them ran with the defaults of its day, taken as today's."""
    return read_settings(run.path, "learner", LearnerConfig) or LearnerConfig()


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
    text = summary_markdown(summary, m, pictures, counts)
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

"""A session's event log summed up per robot, pure (records in, numbers out): its episodes
in the order they happened (a simulator that restarted within the log starts a new run, never
merged by number), their steps, returns and interventions, and the teachers' words."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

from voxshape.protocol import (
    Action,
    CreditedFeedback,
    EpisodeEvent,
    LearningSummary,
    Observation,
    TeachingStats,
    Utterance,
)
from voxshape.services.logger.decoding import (
    Gap,
    Known,
    PresenceChange,
    Rejected,
    Unknown,
    decode_record,
)
from voxshape.services.logger.eventlog import EventRecord
from voxshape.services.logger.run import RunError
from voxshape.world.robot import CONTROL_PERIOD_S

STEP_SECONDS = CONTROL_PERIOD_S  # robot seconds per step
MOVING_AVERAGE = 10  # episodes: the learning curve's mean, and summary.md's recent return


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
    missed: int = 0  # messages the logger missed for good (its gap records)
    nodes: set[str] = field(default_factory=set)
    first_wall: float | None = None
    last_wall: float | None = None

    def robot(self, name: str) -> RobotSummary:
        if name not in self.robots:
            self.robots[name] = RobotSummary(name)
        return self.robots[name]


def summarize_session(records: Iterable[EventRecord], session: str = "") -> SessionSummary:
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
            case Gap(missed=missed):
                summary.missed += missed
            case Unknown():
                summary.unknown_types += 1
            case Rejected():
                summary.rejected += 1
    return summary

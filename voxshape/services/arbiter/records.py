"""What the arbiter keeps of each robot and teacher: a robot's steps, clock, salient events,
episodes (their interventions per teacher) and each teacher's tally; a teacher's reaction
delay."""

from __future__ import annotations

from collections import Counter, OrderedDict
from dataclasses import dataclass, field

from voxshape.services.arbiter.clocks import SimulatorClock
from voxshape.services.arbiter.credit import ReactionDelay, SalientEvents, StepTimeline


@dataclass
class TeacherTally:
    """One teacher's utterances to one robot."""

    utterances: int = 0
    understood: int = 0
    ignored: int = 0


@dataclass
class EpisodeTally:
    """One episode's interventions, until its final statistics are published."""

    interventions: Counter[str] = field(default_factory=Counter)  # per teacher
    ended_at: float | None = None  # arbiter clock
    final: bool = False  # its final statistics were published


@dataclass
class KnownRobot:
    """A robot the arbiter has observed: its steps, clock and salient events, its episodes and
    the tallies of the teachers who spoke to it."""

    timeline: StepTimeline
    clock: SimulatorClock = field(default_factory=SimulatorClock)
    events: SalientEvents = field(default_factory=SalientEvents)
    last_seen: float = 0.0  # arbiter clock
    episodes: OrderedDict[int, EpisodeTally] = field(default_factory=OrderedDict)
    tallies: dict[str, TeacherTally] = field(default_factory=dict)
    changed: bool = False
    stats_sent: float = float("-inf")

    def tally(self, teacher: str) -> TeacherTally:
        return self.tallies.setdefault(teacher, TeacherTally())

    def episode(self, number: int) -> EpisodeTally:
        if number not in self.episodes:
            self.episodes[number] = EpisodeTally()
        return self.episodes[number]


@dataclass
class KnownTeacher:
    """A teacher the arbiter has heard: its reaction delay (a window, learnt or configured)."""

    delay: ReactionDelay

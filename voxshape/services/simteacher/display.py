"""The simulated teacher watching a display (pure: no bus): observations and its own clock
in, words to say out, with their onset and end at the display times of the steps they are
about. Dictates the first `traces` episodes it sees start, then judges through the core
(teacher.py); never says more than `max_words_per_robot_s` things a robot second."""

from __future__ import annotations

import heapq
import math
from bisect import bisect_left
from collections import Counter, deque
from dataclasses import dataclass

from voxshape.protocol import HelpRequest, Observation
from voxshape.runtime.limits import TokenBucket
from voxshape.services.simteacher.teacher import Look, SimulatedTeacher, Speech
from voxshape.world.geodesic import path_command
from voxshape.world.robot import CONTROL_PERIOD_S

COMMAND_EVERY_S = 0.5  # robot seconds between dictated commands (a command steers 5 steps)
DISPLAY_MEMORY = 4096  # steps whose display time is remembered


@dataclass(frozen=True)
class Spoken:
    """Words to send: the text and when the teacher started and stopped saying it (own clock)."""

    text: str
    onset: float
    end: float
    kind: str  # "judgement", "command" or "answer"


class DisplayClock:
    """When each step of the robot was displayed, on the teacher's clock."""

    def __init__(self, memory: int = DISPLAY_MEMORY) -> None:
        self._robot: deque[float] = deque(maxlen=memory)
        self._shown: deque[float] = deque(maxlen=memory)

    def shown(self, robot_time: float, at: float) -> None:
        if self._robot and robot_time < self._robot[-1]:  # the simulator started over
            self._robot.clear()
            self._shown.clear()
        self._robot.append(robot_time)
        self._shown.append(at)

    def at(self, robot_time: float) -> float:
        """The display time of the first step at or after `robot_time` (the latest if none)."""
        i = bisect_left(self._robot, robot_time)
        return self._shown[min(i, len(self._shown) - 1)]


class DisplayTeacher:
    """The teacher between the bus and the core: observations and its own clock in, words to
    say out (pure: no bus). Dictates the first `traces` episodes it sees start, then judges."""

    MAX_WORDS_PER_ROBOT_S = 3.0  # a person says at most 2-3 things a second

    def __init__(
        self,
        teacher: SimulatedTeacher,
        traces: int = 0,
        max_words_per_robot_s: float = MAX_WORDS_PER_ROBOT_S,
        control_period: float = CONTROL_PERIOD_S,
        counters: Counter[str] | None = None,
    ) -> None:
        self.teacher = teacher
        self.traces = traces
        self.control_period = control_period
        self.counters: Counter[str] = Counter() if counters is None else counters
        self.display = DisplayClock()
        self.max_words_per_robot_s = max_words_per_robot_s
        self._bucket: TokenBucket | None = None
        self._pending: list[
            tuple[float, int, str, float, str]
        ] = []  # (end, order, text, onset, kind)
        self._look: Look | None = None  # the latest step judged
        self._order = 0
        self._started = 0  # episodes seen from their start
        self._episode: int | None = None  # the simulator's episode being watched
        self._dictating = False
        self._next_command = -math.inf

    def on_observation(self, obs: Observation, now: float) -> list[Spoken]:
        t = obs.step * self.control_period  # robot seconds
        self.display.shown(t, now)
        if obs.episode != self._episode:
            self._episode = obs.episode
            seen_start = obs.episode_step == 0
            self._started += seen_start
            self._dictating = seen_start and self._started <= self.traces
            self._next_command = -math.inf
        out: list[Spoken] = []
        if self._dictating:
            if obs.outcome == "running" and t >= self._next_command - 1e-9:
                self._next_command = t + COMMAND_EVERY_S
                text = self.teacher.phrase(path_command(self.teacher.map, obs.x, obs.y, obs.theta))
                out.append(Spoken(text, now, now, "command"))
        else:
            episode = max(0, self._started - self.traces - 1)  # of the episodes it judges
            self._look = Look(t, episode, obs.x, obs.y, obs.collided, obs.outcome, obs.theta)
            for speech in self.teacher.watch(self._look):
                self._pend(speech, "judgement")
        while self._pending and self._pending[0][0] <= t + 1e-9:
            end, _, text, onset, kind = heapq.heappop(self._pending)
            out.append(Spoken(text, self.display.at(onset), self.display.at(end), kind))
        return [s for s in out if self._may_say(s, t)]

    def on_question(self, question: HelpRequest) -> None:
        """The robot asks which way: the answer (if the budget allows) is said like the
        judgements, after its reaction, from what the teacher sees now."""
        if self._look is None or self._dictating or question.episode != self._episode:
            return
        if (speech := self.teacher.answer(self._look)) is not None:
            self._pend(speech, "answer")

    def _pend(self, speech: Speech, kind: str) -> None:
        """Said once the step at the end of the speech is displayed."""
        heapq.heappush(self._pending, (speech.end, self._order, speech.said, speech.onset, kind))
        self._order += 1

    def _may_say(self, spoken: Spoken, t: float) -> bool:
        if self._bucket is None or t < self._bucket.updated:  # none yet, or a new simulator
            most = self.max_words_per_robot_s
            self._bucket = TokenBucket(most, max(1.0, most), t)
        if self._bucket.take(t):
            self.counters[f"said.{spoken.kind}"] += 1
            return True
        self.counters[f"unsaid.{spoken.kind}.too_fast"] += 1
        return False

"""Where each robot stands as a session's messages go by: its latest step, simulated time and
episode, and when each recent step was observed (the recording places feedback and utterances
with it). Pure. Interventions are not counted here: the arbiter's count (TeachingStats) is the
one the recording, the report and the demo show."""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

from voxshape.protocol import EpisodeEvent, Observation
from voxshape.services.logger.decoding import Decoded, Known

REMEMBERED_STEPS = 20_000  # steps whose times are kept, for feedback credited to past steps


@dataclass(frozen=True)
class StepTime:
    sim_time: float
    wall_time: float  # when the logger received the step's observation
    episode: int


@dataclass
class RobotTally:
    robot: str
    step: int | None = None  # the latest observed step
    sim_time: float = 0.0
    episode: int = 0
    observations: int = 0
    _times: OrderedDict[int, StepTime] = field(default_factory=OrderedDict, repr=False)

    def time_of(self, step: int) -> StepTime | None:
        """When `step` was observed (for the last REMEMBERED_STEPS steps)."""
        return self._times.get(step)

    def _observed(self, obs: Observation, received: float) -> None:
        self.step, self.sim_time, self.episode = obs.step, obs.sim_time, obs.episode
        self.observations += 1
        self._times[obs.step] = StepTime(obs.sim_time, received, obs.episode)
        if len(self._times) > REMEMBERED_STEPS:
            self._times.popitem(last=False)


class SessionTally:
    def __init__(self) -> None:
        self.robots: dict[str, RobotTally] = {}

    def robot(self, name: str) -> RobotTally:
        if name not in self.robots:
            self.robots[name] = RobotTally(name)
        return self.robots[name]

    def observe(self, decoded: Decoded) -> None:
        """Updates the tally with one decoded record (call before rendering it)."""
        if not isinstance(decoded, Known):
            return
        message = decoded.message
        if isinstance(message, Observation):
            self.robot(message.robot)._observed(message, decoded.record.received)
        elif isinstance(message, EpisodeEvent) and message.kind == "start":
            self.robot(message.robot).episode = message.episode

"""When the robot asks "which way?": the learner knows where a word would help most.

It asks when it is stuck (its own value estimate max_a Q(s, a) has not risen, or it keeps
bumping, for `stuck_s` robot seconds), when an episode has run `late_share` of its timeout,
or where its values are flat and no teacher has advised it; once it has reached the goal, only
in episodes `beyond_fastest` times longer than its fastest. At most `per_robot_minute`
questions a robot minute (a token bucket of its own), never while one is open (the protocol's
QUESTION_OPEN_S), and not again where it already asked until an answer has been tried there.
A policy beside the learner: the answer (a command naming the question's id) goes to the
learner as every word does (agent.py), which tells the asker it came (`answered`). Pure:
percepts in, questions out."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Literal

from voxshape.protocol import QUESTION_OPEN_S, HelpRequest
from voxshape.protocol.messages import new_message_id
from voxshape.runtime.limits import TokenBucket
from voxshape.services.learner.sarsa import Learner, LearnerPercept
from voxshape.world.robot import CONTROL_PERIOD_S

Reason = Literal["stuck", "late", "unsure"]


@dataclass(frozen=True)
class Question:
    """The robot asks which way, at observation `step`, for a reason."""

    step: int
    episode: int
    reason: Reason
    detail: str  # e.g. "stuck for 10 s", for the teachers
    id: str = field(default_factory=new_message_id)  # its HelpRequest's: the answer names it

    def request(self, robot: str, x: float, y: float) -> HelpRequest:
        """The question as the bus carries it, from where the robot is."""
        return HelpRequest(
            id=self.id,
            robot=robot,
            episode=self.episode,
            step=self.step,
            reason=self.reason,
            detail=self.detail,
            x=x,
            y=y,
        )


class Asker:
    """Decides, step by step, whether the robot asks; told when an answer came."""

    def __init__(self, learner: Learner, timeout_s: float) -> None:
        self.learner = learner
        self.config = learner.config.ask
        self.timeout_s = timeout_s
        self.budget = TokenBucket(self.config.per_robot_minute / 60, 1.0, now=0.0)
        # The open question, when it was asked and the state (key) it was asked in.
        self.open: tuple[Question, float, int] | None = None
        self._asked_views: set[int] = set()  # asked there, no answer tried yet
        self._best = (-math.inf, 0.0)  # (best max_a Q this episode, when)
        self._bumps: list[float] = []
        self.reasons: Counter[str] = Counter()  # questions asked, by reason
        self._fastest = math.inf  # robot seconds of its fastest episode to the goal

    def after_step(self, p: LearnerPercept, episode: int) -> Question | None:
        """The robot after the learner's step to `p`: a question, or None."""
        t, episode_t = p.step * CONTROL_PERIOD_S, p.episode_step * CONTROL_PERIOD_S
        if p.outcome == "goal":
            self._fastest = min(self._fastest, episode_t)
        if p.episode_step == 0:
            self._new_episode(t)
        s = self.learner.s
        if s is None or episode_t <= self.config.beyond_fastest * self._fastest < math.inf:
            return None
        q = self.learner.q(s)
        if q.max() > self._best[0] + 1e-9:
            self._best = (float(q.max()), t)
        if p.collided:
            self._bumps = [b for b in self._bumps if t - b < self.config.stuck_s] + [t]
        if self.open is not None and t - self.open[1] > QUESTION_OPEN_S:
            self.open = None  # nobody answered: the budget says when to ask again
        spoken = self.learner.way.spoken_at((p.x, p.y))
        reason = self._reason(t, episode_t, q.max() - q.min(), spoken)
        if reason is None or self.open is not None or s in self._asked_views:
            return None
        if self.config.per_robot_minute <= 0 or not self.budget.take(t):
            return None
        question = Question(p.step, episode, reason, self._detail(reason, t, episode_t))
        self.open = (question, t, s)
        self._asked_views.add(s)
        self.reasons[reason] += 1
        return question

    def answered(self, question_id: str) -> int | None:
        """An answer to the question `question_id` came: if it is the open one, it is closed,
        the robot may ask again in the state it asked in (an answer is tried there), and that
        state is returned (else None)."""
        if self.open is None or self.open[0].id != question_id:
            return None
        asked_in = self.open[2]
        self._asked_views.discard(asked_in)
        self.open = None
        return asked_in

    def _reason(self, t: float, episode_t: float, spread: float, advised: bool) -> Reason | None:
        c = self.config
        if t - self._best[1] >= c.stuck_s or len(self._bumps) >= c.bumps:
            return "stuck"
        if episode_t >= c.late_share * self.timeout_s:
            return "late"
        if spread < c.flat and not advised:
            return "unsure"
        return None

    def _detail(self, reason: Reason, t: float, episode_t: float) -> str:
        if reason == "stuck":
            return f"stuck for {t - self._best[1]:.0f} s"
        if reason == "late":
            return f"{episode_t:.0f} s into an episode of at most {self.timeout_s:.0f} s"
        return "never taught here"

    def _new_episode(self, t: float) -> None:
        self._best = (-math.inf, t)
        self._bumps.clear()
        self._asked_views.clear()
        self.open = None

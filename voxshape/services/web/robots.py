"""The robots of the session as every page sees them: which exist, their observations
thinned to a rate, the learning curve, and their open questions (bounded, for every page and
for pages that join late)."""

from __future__ import annotations

from collections import deque
from typing import Any

from voxshape.protocol import (
    EpisodeEvent,
    HelpAnswer,
    HelpRequest,
    Learnt,
    Observation,
    TeachingStats,
)
from voxshape.runtime.limits import Throttle, TokenBucket
from voxshape.services.web.page_json import (
    SessionView,
    answer_json,
    episode_json,
    learnt_json,
    obs_json,
    question_json,
)

OBS_HZ = 10.0  # observations forwarded per robot and second, at most ...
OBS_AT_ONCE = 2.0  # ... and at once (a late frame and the next one)


CURVE_KEPT = 1000  # ended episodes the welcome replays to a page that joins late


QUESTION_EVERY_S = 1.0  # a robot's questions (and answers) forwarded at most this often
QUESTIONS_PER_S = 5.0  # ... and all robots' together (a burst of QUESTIONS_BURST)
QUESTIONS_BURST = 10.0
QUESTION_OPEN_S = 10.0  # a page that joins this soon after an unanswered question is shown it
MAX_OPEN_QUESTIONS = 64  # open questions remembered for pages that join (the oldest forgotten)


class Robots:
    """The robots of the session as the pages see them: which exist, their observations
    thinned to `hz` a second each (a token bucket per robot, 2 at once: at the simulator's
    own 10 Hz none waits; faster, the latest wins, sent when a token comes), and the learning
    curve (an ended episode's point once the arbiter's count of it is final)."""

    def __init__(self, hz: float = OBS_HZ) -> None:
        self.hz = hz
        self.seen: list[str] = []
        self._slots: dict[str, TokenBucket] = {}
        self._pending: dict[str, Observation] = {}
        self._ended: dict[tuple[str, int], EpisodeEvent] = {}
        self.curve: deque[dict[str, Any]] = deque(maxlen=CURVE_KEPT)
        self._asked: dict[str, tuple[dict[str, Any], float]] = {}  # robot -> open question
        self.learnt: dict[str, dict[str, Any]] = {}  # robot -> that it has learnt its task
        self._per_robot = Throttle(QUESTION_EVERY_S)
        self._all = TokenBucket(QUESTIONS_PER_S, QUESTIONS_BURST)

    def _see(self, robot: str) -> None:
        if robot not in self.seen:
            self.seen.append(robot)

    def observation(self, obs: Observation, now: float) -> list[dict[str, Any]]:
        """The observation to forward now, if its robot's slot has come; else it waits."""
        self._see(obs.robot)
        self._pending[obs.robot] = obs
        return self.due(now)

    def due(self, now: float) -> list[dict[str, Any]]:
        """Waiting observations whose slot has come (call it a few times per period)."""
        out = []
        for robot, obs in list(self._pending.items()):
            slots = self._slots.get(robot)
            if slots is None:
                slots = self._slots[robot] = TokenBucket(self.hz, OBS_AT_ONCE, now)
            if slots.take(now):
                del self._pending[robot]
                out.append(obs_json(obs, now))
        return out

    def episode(self, event: EpisodeEvent) -> list[dict[str, Any]]:
        self._see(event.robot)
        if event.kind != "start":
            self._ended[(event.robot, event.episode)] = event
            while len(self._ended) > CURVE_KEPT:
                self._ended.pop(next(iter(self._ended)))
        return [episode_json(event)]

    def teaching(self, stats: TeachingStats) -> list[dict[str, Any]]:
        """The curve's point of an episode whose interventions are final."""
        ended = self._ended.pop((stats.robot, stats.episode), None) if stats.final else None
        if ended is None:
            return []
        point = {
            "type": "curve",
            "robot": stats.robot,
            "episode": stats.episode,
            "kind": ended.kind,
            "return": ended.env_return,
            "steps": ended.episode_steps,
            "interventions": stats.interventions,
        }
        self.curve.append(point)
        return [point]

    def _bounded(self, kind: str, robot: str, now: float) -> bool:
        """Whether a question (or answer) goes out: one a robot per QUESTION_EVERY_S, and
        QUESTIONS_PER_S of all robots; the excess is dropped."""
        return self._per_robot.due((kind, robot), now) and self._all.take(now)

    def question(
        self, question: HelpRequest, now: float, key_robot: str | None = None
    ) -> list[dict[str, Any]]:
        """A robot's question for every page (none claiming another robot than its key's,
        `key_robot`); remembered for pages that join while it is open."""
        if key_robot not in (None, question.robot):
            return []
        if not self._bounded("question", question.robot, now):
            return []
        item = question_json(question, now)
        self._asked.pop(question.robot, None)
        self._asked[question.robot] = (item, now)
        for robot, (_, at) in list(self._asked.items()):
            if now - at >= QUESTION_OPEN_S or len(self._asked) > MAX_OPEN_QUESTIONS:
                del self._asked[robot]  # oldest first
        return [item]

    def answer(self, answer: HelpAnswer, now: float) -> list[dict[str, Any]]:
        """Who answered a robot's question: for every page; the question is no longer open."""
        if not self._bounded("answer", answer.robot, now):
            return []
        asked = self._asked.get(answer.robot)
        if asked is not None and asked[0]["question"] == answer.question:
            del self._asked[answer.robot]
        return [answer_json(answer)]

    def has_learnt(self, learnt: Learnt) -> list[dict[str, Any]]:
        """A robot has learnt its task: every page says so, and those that join later."""
        self._see(learnt.robot)
        self.learnt[learnt.robot] = learnt_json(learnt)
        while len(self.learnt) > CURVE_KEPT:  # robots that came and went
            self.learnt.pop(next(iter(self.learnt)))
        return [self.learnt[learnt.robot]]

    def open_questions(self, now: float) -> list[dict[str, Any]]:
        """Questions asked within QUESTION_OPEN_S that nobody answered, oldest first."""
        return [item for item, at in self._asked.values() if 0 <= now - at < QUESTION_OPEN_S]

    def welcome(self, view: SessionView, teacher: str, now: float) -> dict[str, Any]:
        return {
            "type": "welcome",
            "session": view.session,
            "teacher": teacher,
            "secured": view.secured,
            "robots": list(self.seen),
            "language": view.language,
            "vocabulary": view.vocabulary,
            "map": view.map,
            "viewer": view.viewer,
            "curve": list(self.curve),
            "questions": self.open_questions(now),
            "learnt": list(self.learnt.values()),
        }

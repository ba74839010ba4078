"""The robots' open questions ("which way?", HelpRequest): the first understood command said
within the protocol's QUESTION_OPEN_S of a question answers it, and is credited to the
question's step whatever the teacher's learnt delay; other words are judged as any other."""

from __future__ import annotations

from dataclasses import dataclass

from voxshape.protocol import QUESTION_OPEN_S, HelpRequest

EARLY_S = 0.5  # an onset this much before the question still answers it (clocks are not exact)


@dataclass(frozen=True)
class AskedQuestion:
    """A robot's question as the arbiter holds it open: which, where the robot was (step,
    episode) and when it was asked."""

    id: str
    robot: str
    step: int
    episode: int
    asked_at: float  # arbiter clock


class OpenQuestions:
    """At most one open question per robot: a new one replaces the last."""

    def __init__(self) -> None:
        self._open: dict[str, AskedQuestion] = {}

    def ask(self, request: HelpRequest, received_at: float) -> None:
        self._open[request.robot] = AskedQuestion(
            request.id, request.robot, request.step, request.episode, received_at
        )

    def answered_by(self, robot: str, onset: float, scale: float = 1.0) -> AskedQuestion | None:
        """The question a word said at `onset` (arbiter clock) answers, closed; `scale`: wall
        seconds per second of the teacher's."""
        question = self._open.get(robot)
        if question is None:
            return None
        if not -EARLY_S * scale <= onset - question.asked_at <= QUESTION_OPEN_S * scale:
            return None
        del self._open[robot]
        return question

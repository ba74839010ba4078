"""The messages the arbiter sends, built from what it decided: credited feedback (a command, the
answer to a robot's question, merged rewards) with ids derived from its sources, and the notice
that tells a teacher what became of a word, in a sentence that says what to do."""

from __future__ import annotations

import hashlib
from collections.abc import Iterable

from voxshape.protocol import (
    Credit,
    CreditedFeedback,
    HelpAnswer,
    TeacherNotice,
    Utterance,
    Vocabulary,
)
from voxshape.protocol.messages import NoticeKind
from voxshape.services.arbiter.credit import MAX_CREDITS
from voxshape.services.arbiter.meaning import examples_of
from voxshape.services.arbiter.merge import Merged
from voxshape.services.arbiter.questions import AskedQuestion

MAX_TEXT = 500  # characters of a notice's text


def feedback_id(robot: str, kind: str, sources: tuple[str, ...]) -> str:
    """A feedback message's id, derived from the utterances it comes from: an arbiter that
    restarts and derives it again from the utterances it recovers gives it the same id, so a
    learner that took it before skips it."""
    key = "|".join((robot, kind, *sorted(sources))).encode()
    return hashlib.blake2b(key, digest_size=16).hexdigest()


def command_feedback(
    utterance: Utterance,
    action: str,
    step: int | tuple[tuple[int, float], ...],
    question: str | None = None,
) -> CreditedFeedback:
    """A command (the learner carries it out now), credited to `step` alone or to the steps
    the teacher saw when deciding it (credits), answering the HelpRequest `question` if
    given; its id is the one of a command from that utterance, so it is sent once whether it
    answers a question or not."""
    steps = ((step, 1.0),) if isinstance(step, int) else step
    credits = tuple(Credit(step=s, weight=w) for s, w in steps)
    return CreditedFeedback(
        id=feedback_id(utterance.robot, "command", (utterance.id,)),
        robot=utterance.robot,
        kind="command",
        reward=None,
        command=action,  # type: ignore[arg-type]
        credits=credits,
        sources=(utterance.id,),
        teachers=(utterance.teacher,),
        question=question,
    )


def help_answer(utterance: Utterance, action: str, question: AskedQuestion) -> HelpAnswer:
    """Who answered a robot's question, with what."""
    return HelpAnswer(
        robot=utterance.robot,
        question=question.id,
        step=question.step,
        teacher=utterance.teacher,
        meaning=action,
        utterance=utterance.id,
    )


def reward_feedback(merged: Merged) -> CreditedFeedback:
    """The merged reward over at most MAX_CREDITS credits (the learner's g bounds it)."""
    credits = merged.credits
    if len(credits) > MAX_CREDITS:
        credits = tuple(sorted(sorted(credits, key=lambda c: -c[1])[:MAX_CREDITS]))
    total = sum(w for _, w in credits)
    return CreditedFeedback(
        id=feedback_id(merged.robot, "reward", merged.sources),
        robot=merged.robot,
        kind="reward",
        reward=merged.reward,
        command=None,
        credits=tuple(Credit(step=s, weight=min(1.0, w / total)) for s, w in credits),
        sources=merged.sources[:64],
        teachers=merged.teachers[:64],
    )


def notice(utterance: Utterance, kind: NoticeKind, text: str, meaning: str | None) -> TeacherNotice:
    """What became of an utterance, for the teacher who said it."""
    return TeacherNotice(
        teacher=utterance.teacher,
        robot=utterance.robot,
        utterance=utterance.id,
        kind=kind,
        meaning=meaning[:32] if meaning else None,
        text=text[:MAX_TEXT],
    )


def explain(
    reason: str,
    utterance: Utterance,
    detail: str,
    vocabulary: Vocabulary,
    utterances_per_s: float,
    robots: Iterable[str],
) -> str:
    """Why an utterance was not used, in a sentence that says what to do."""
    if reason == "low_confidence":
        return f"not used: {detail}; say it again, clearly"
    if reason == "not_understood":
        said = examples_of(vocabulary, utterance.language)
        return f"not understood: {detail}; say e.g. {said}"
    if reason == "rate_limited":
        return (
            f"not used: too many words, at most {utterances_per_s:g} a second; "
            "slow down (words beyond it are ignored, told once a second)"
        )
    if reason == "unknown_robot":
        known = ", ".join(robots) or "none yet"
        return f"not used: no robot {utterance.robot!r} runs in this session (robots: {known})"
    return "too late: the steps you mean are no longer remembered; say it sooner"

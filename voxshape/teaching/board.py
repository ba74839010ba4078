"""What a teacher sees (pure): the robot's status, and one line per utterance saying what
became of it, only once the arbiter (or the speech service) said so, or that nobody did."""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Literal

from voxshape.protocol import (
    CreditedFeedback,
    EpisodeEvent,
    HelpAnswer,
    HelpRequest,
    Observation,
    TeacherNotice,
    Utterance,
)

ANSWER_WITHIN_S = 1.0  # an utterance nobody answered within this is told as such


@dataclass(frozen=True)
class Shown:
    """One thing to show: `text` for people, `data` (with its `event`) for --json."""

    event: str
    text: str
    data: dict = field(default_factory=dict)

    def as_json(self) -> dict:
        return {"event": self.event, **self.data}


class Board:
    def __init__(
        self,
        status_every_s: float = 2.0,
        answer_within_s: float = 1.0,
        no_answer_hint: str = "no arbiter heard it",
        robot_missing: str = "",
        started_at: float = 0.0,
        ask_hint: str = "",
    ) -> None:
        """`no_answer_hint`: what to tell the teacher when an utterance gets no answer;
        `robot_missing`: when no observation of the robot came within `answer_within_s` of
        `started_at` (empty: not watched); `ask_hint`: what to say to a robot's question
        (e.g. "say left, right or forward")."""
        self.status_every_s = status_every_s
        self.ask_hint = ask_hint
        self.robot_missing = robot_missing
        self._started_at = started_at
        self._robot_seen = self._robot_missing_told = False
        self.answer_within_s = answer_within_s
        self.no_answer_hint = no_answer_hint
        self._last_status = float("-inf")
        self.last_feedback: CreditedFeedback | None = None
        self._pending: dict[str, _Pending] = {}
        self._late: OrderedDict[str, _Pending] = OrderedDict()
        self._early: OrderedDict[str, tuple[TeacherNotice, float]] = OrderedDict()
        self._rate_limited_at = float("-inf")

    @property
    def robot_never_seen(self) -> bool:
        """Whether it said the robot is missing and the robot never showed up."""
        return self._robot_missing_told and not self._robot_seen

    def observation(self, obs: Observation, now: float) -> list[Shown]:
        """The robot's status, at most every `status_every_s`."""
        back = []
        if not self._robot_seen and self._robot_missing_told:
            back = [Shown("robot", f"robot {obs.robot} is running now", {"robot": obs.robot})]
        self._robot_seen = True
        if now - self._last_status < self.status_every_s:
            return back
        self._last_status = now
        data = {
            "robot": obs.robot,
            "episode": obs.episode,
            "step": obs.step,
            "episode_step": obs.episode_step,
            "reward": obs.reward,
            "goal_distance": round(obs.goal_distance, 3),
        }
        text = (
            f"robot {obs.robot}: episode {obs.episode}, step {obs.episode_step} "
            f"({obs.step} in all), last reward {obs.reward:+g}, "
            f"{obs.goal_distance:.1f} m to the goal"
        )
        return [*back, Shown("status", text, data)]

    def episode(self, event: EpisodeEvent) -> list[Shown]:
        data = {
            "robot": event.robot,
            "episode": event.episode,
            "kind": event.kind,
            "steps": event.episode_steps,
            "return": event.env_return,
        }
        if event.kind == "start":
            text = f"robot {event.robot}: episode {event.episode} starts"
        else:
            text = (
                f"robot {event.robot}: episode {event.episode} ended: {event.kind} after "
                f"{event.episode_steps} steps, return {event.env_return:+g}"
            )
        return [Shown("episode", text, data)]

    def feedback(self, feedback: CreditedFeedback) -> list[Shown]:
        self.last_feedback = feedback
        what = f"reward {feedback.reward:+g}" if feedback.kind == "reward" else feedback.command
        steps = [c.step for c in feedback.credits]
        text = (
            f"robot {feedback.robot} took {what} from {', '.join(feedback.teachers)} "
            f"(steps {min(steps)}-{max(steps)})"
        )
        data = {
            "robot": feedback.robot,
            "kind": feedback.kind,
            "reward": feedback.reward,
            "command": feedback.command,
            "teachers": list(feedback.teachers),
            "steps": steps,
        }
        return [Shown("feedback", text, data)]

    # -- the robot asks "which way?", and who answered ---------------------------------------
    def question(self, q: HelpRequest) -> list[Shown]:
        """A robot's question: "r1 asks: which way? stuck for 10 s", and the hint."""
        asked = f"{q.robot} asks: which way? {printable(q.detail, MAX_DETAIL)}".rstrip()
        text = f"{asked} — {self.ask_hint}" if self.ask_hint else asked
        data = {
            "robot": q.robot,
            "question": q.id,
            "episode": q.episode,
            "step": q.step,
            "reason": q.reason,
            "detail": q.detail,
            "x": round(q.x, 4),
            "y": round(q.y, 4),
            "message": asked,
        }
        return [Shown("question", text, data)]

    def answer(self, a: HelpAnswer) -> list[Shown]:
        """Who answered a robot's question, with what: "answered by ana: left"."""
        text = f"answered by {a.teacher}: {printable(a.meaning, MAX_DETAIL)}"
        data = {
            "robot": a.robot,
            "question": a.question,
            "step": a.step,
            "teacher": a.teacher,
            "meaning": a.meaning,
            "utterance": a.utterance,
            "message": text,
        }
        return [Shown("answer", text, data)]

    # -- what became of each utterance: one line each, once the arbiter (or speech) says ------
    @property
    def waiting(self) -> bool:
        """Whether an utterance still awaits its answer (for at most `answer_within_s`)."""
        return bool(self._pending)

    def sent(self, u: Utterance, now: float) -> list[Shown]:
        """An utterance this client sent (typed): awaits its notice."""
        self._pending.setdefault(u.id, _Pending(u, now))
        return []

    def recognized(self, u: Utterance, now: float) -> list[Shown]:
        """What the speech service made of this teacher's speech (or the echo of a typed one):
        nothing is shown until the arbiter says what it made of it, unless it already has (the
        verdict overtook the utterance: zenoh orders messages per key only)."""
        self.sent(u, now)
        early = self._early.pop(u.id, None)
        return [] if early is None else self.notice(early[0], now)

    def notice(self, n: TeacherNotice, now: float) -> list[Shown]:
        """The verdict on one utterance: understood, or why not (from the arbiter), or speech
        that the speech service rejected. A verdict on an utterance not seen yet waits for it
        (shown with what was heard), `answer_within_s` at most."""
        known = n.utterance in self._pending or n.utterance in self._late
        if not known and n.kind != "not_recognized":  # speech's rejections have no utterance
            self._early[n.utterance] = (n, now)
            if len(self._early) > MAX_REMEMBERED:
                self._early.popitem(last=False)
            return []
        return self._verdict(n, now)

    def _verdict(self, n: TeacherNotice, now: float) -> list[Shown]:
        if n.kind == "rate_limited":
            self._rate_limited_at = now
        late = n.utterance in self._late
        pending = self._late.pop(n.utterance) if late else self._pending.pop(n.utterance, None)
        data = {
            "robot": n.robot,
            "utterance": n.utterance,
            "kind": n.kind,
            "meaning": n.meaning,
            "message": n.text,
            "late": late,
            **(_heard(pending.utterance) if pending else {}),
        }
        how = f" ({_how(pending.utterance)})" if pending else ""
        text = ("late answer: " if late else "") + n.text + how
        return [Shown("notice", text, data)]

    def tick(self, now: float) -> list[Shown]:
        """Utterances nobody answered within `answer_within_s`: say so, once each; and a robot
        that nothing was seen of."""
        out = []
        if (
            self.robot_missing
            and not (self._robot_seen or self._robot_missing_told)
            and now - self._started_at >= self.answer_within_s
        ):
            self._robot_missing_told = True
            out.append(Shown("robot", self.robot_missing, {"message": self.robot_missing}))
        for id_, (n, since) in list(self._early.items()):
            if now - since >= self.answer_within_s:  # its utterance never came: shown as is
                del self._early[id_]
                out += self._verdict(n, now)
        for id_, pending in list(self._pending.items()):
            if now - pending.since < self.answer_within_s:
                continue
            del self._pending[id_]
            self._late[id_] = pending
            if len(self._late) > MAX_REMEMBERED:
                self._late.popitem(last=False)
            u = pending.utterance
            if now - self._rate_limited_at < RATE_LIMIT_MEMORY_S:
                why = "you were rate limited a moment ago: words beyond the limit are ignored"
            else:
                why = self.no_answer_hint
            text = f"no answer to {u.text!r} within {self.answer_within_s:g} s: {why}"
            data = {"robot": u.robot, "utterance": u.id, **_heard(u), "why": why}
            out.append(Shown("no_answer", text, data))
        return out


@dataclass(frozen=True)
class _Pending:
    utterance: Utterance
    since: float


MAX_REMEMBERED = 256  # utterances told "no answer", kept to show a late answer
RATE_LIMIT_MEMORY_S = 2.0  # a rate-limited notice explains silences this long after it


MAX_DETAIL = 120  # characters of a question's detail (or an answer's meaning) shown


def printable(text: str, limit: int) -> str:
    """Bus text as a terminal may print it: no control characters (escape sequences), at most
    `limit` characters."""
    shown = "".join(c if c.isprintable() else "?" for c in text)
    return shown if len(shown) <= limit else shown[: limit - 1] + "…"


def _how(u: Utterance) -> str:
    return "typed" if u.engine == "typed" else f"{u.engine}, confidence {u.confidence:.2f}"


def _heard(u: Utterance) -> dict:
    return {"text": u.text, "engine": u.engine, "confidence": u.confidence, "onset": u.onset}


SpeechUse = Literal["audio", "through_speech", "typed"]


class SpeechWatch:
    """Which speech services are present, and what their going and coming back means to this
    teacher (`use`: how its words travel). Says nothing until one is lost: a teacher who
    streams audio was already told at start if none was there."""

    def __init__(self, use: SpeechUse) -> None:
        self.use = use
        self.present: set[str] = set()
        self.lost = False

    @property
    def available(self) -> bool:
        return bool(self.present)

    def change(self, node: str, alive: bool) -> list[Shown]:
        was = self.available
        (self.present.add if alive else self.present.discard)(node)
        data = {"node": node, "available": self.available, "use": self.use}
        if was and not self.available:
            self.lost = True
            return [
                Shown("speech", _SPEECH_GONE[self.use], {"message": _SPEECH_GONE[self.use], **data})
            ]
        if self.lost and not was and self.available:
            text = f"speech service {node} is back: " + _SPEECH_BACK[self.use]
            return [Shown("speech", text, {"message": text, **data})]
        return []


_SPEECH_GONE = {
    "audio": "the speech service is gone: what you say is NOT heard until it is back "
    "(`voxshape speech`); typed words still work: run `voxshape teach` without --wav/--mic",
    "through_speech": "the speech service is gone: your typed words now go straight to the "
    "arbiter (not through speech) until it is back",
    "typed": "the speech service is gone (your typed words are not affected)",
}
_SPEECH_BACK = {
    "audio": "what you say is heard again",
    "through_speech": "typed words go through speech again",
    "typed": "spoken words are heard again",
}

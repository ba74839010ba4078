"""What a teacher sees: the robot's status and what was understood of each utterance (pure)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from protocol import CreditedFeedback, EpisodeEvent, Observation, TeacherNotice, Utterance
from protocol.vocabulary import Vocabulary


@dataclass(frozen=True)
class Shown:
    """One thing to show: `text` for people, `data` (with its `event`) for --json."""

    event: str
    text: str
    data: dict = field(default_factory=dict)

    def as_json(self) -> dict:
        return {"event": self.event, **self.data}


def meaning_of(vocabulary: Vocabulary, text: str) -> str:
    meaning = vocabulary.lookup(text)
    if meaning is None:
        return "not in the vocabulary"
    if meaning.kind == "command":
        return f"command {meaning.action}"
    return f"{meaning.kind} {meaning.reward:+g}"


class Board:
    def __init__(self, vocabulary: Vocabulary, status_every_s: float = 2.0) -> None:
        self.vocabulary = vocabulary
        self.status_every_s = status_every_s
        self._last_status = float("-inf")
        self.last_feedback: CreditedFeedback | None = None

    def observation(self, obs: Observation, now: float) -> list[Shown]:
        """The robot's status, at most every `status_every_s`."""
        if now - self._last_status < self.status_every_s:
            return []
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
        return [Shown("status", text, data)]

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

    def understood(self, u: Utterance) -> list[Shown]:
        meaning = meaning_of(self.vocabulary, u.text)
        how = "typed" if u.engine == "typed" else f"{u.engine}, confidence {u.confidence:.2f}"
        text = f"understood {u.text!r}: {meaning} ({how})"
        data = {
            "teacher": u.teacher,
            "robot": u.robot,
            "text": u.text,
            "meaning": meaning,
            "confidence": u.confidence,
            "engine": u.engine,
            "language": u.language,
            "onset": u.onset,
            "end": u.end,
            "recognized_at": u.recognized_at,
        }
        return [Shown("understood", text, data)]

    def notice(self, n: TeacherNotice) -> list[Shown]:
        """The arbiter's verdict on one utterance: understood, or why it was ignored."""
        data = {"robot": n.robot, "utterance": n.utterance, "kind": n.kind, "meaning": n.meaning}
        return [Shown("notice", f"arbiter: {n.text}", data)]


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

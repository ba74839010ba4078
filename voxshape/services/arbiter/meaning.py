"""What an utterance means: the vocabulary decides (it is the only source of word meanings),
after a confidence gate, by one rule for typed and spoken words: the whole utterance, else a
phrase inside it unless negated ("could you go left": left; "no good": nothing). Phrases
match in any of the vocabulary's languages, whatever the utterance's `language` says: a
bilingual teacher may mix them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from voxshape.protocol import Meaning, Vocabulary


@dataclass(frozen=True)
class Understood:
    meaning: Meaning

    @property
    def is_command(self) -> bool:
        return self.meaning.kind == "command"


@dataclass(frozen=True)
class NotUnderstood:
    reason: Literal["low_confidence", "not_understood"]
    detail: str  # for the teacher and the log


def interpret(
    text: str, confidence: float, vocabulary: Vocabulary, min_confidence: float
) -> Understood | NotUnderstood:
    """The meaning of a whole utterance, or why it has none. Confidence is checked first: a
    recognizer unsure of what it heard must not turn it into a reward."""
    if confidence < min_confidence:
        return NotUnderstood(
            "low_confidence",
            f"heard {text!r} with confidence {confidence:.2f}, below {min_confidence:.2f}",
        )
    meaning, phrase, negated = vocabulary.find(text)  # as the speech engines spot it
    if negated:
        return NotUnderstood("not_understood", f"{phrase!r} is negated in {text!r}: nothing")
    if meaning is None:
        return NotUnderstood("not_understood", f"{text!r} is not in the vocabulary")
    return Understood(meaning)


def examples_of(vocabulary: Vocabulary, language: str, n: int = 4) -> str:
    """A few phrases of the vocabulary, to tell a teacher what works: the first of the first
    `n` meanings of each kind (qualifiers, then commands; the goal's too)."""
    firsts: dict[str, list[str]] = {}
    for m in vocabulary.meanings.values():
        if m.phrases.get(language):
            firsts.setdefault(m.kind, []).append(m.phrases[language][0])
    kinds = ("qualifier", "command", "goal")
    return ", ".join(p for kind in kinds for p in firsts.get(kind, [])[:n])

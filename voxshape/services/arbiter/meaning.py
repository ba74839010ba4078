"""What an utterance means: the vocabulary decides (it is the only source of word meanings),
after a confidence gate. Phrases match in any of the vocabulary's languages, whatever the
utterance's `language` says: a bilingual teacher may mix them."""

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
    meaning = vocabulary.lookup(text)
    if meaning is None:
        return NotUnderstood("not_understood", f"{text!r} is not in the vocabulary")
    return Understood(meaning)


def examples_of(vocabulary: Vocabulary, language: str, n: int = 5) -> str:
    """A few phrases of the vocabulary (the first of each meaning), to tell a teacher what works."""
    firsts = [
        m.phrases[language][0] for m in vocabulary.meanings.values() if m.phrases.get(language)
    ]
    return ", ".join(firsts[:n])

"""The recognition confusion model: what a grammar-restricted recognizer makes of a phrase said
as text, with its errors. The speech service's mock engine runs it
(voxshape/services/speech/mock.py), and the simulated teacher models through it what it is heard as.

Its input is a phrase said as text. Like the real engines, it only ever outputs whole phrases
of the vocabulary, so its errors are whole phrases too. With probability `error_rate` an
utterance is not recognized as said; the kind of error is drawn by weight:

- misheard: another phrase of the same language comes out instead;
- dropped: nothing comes out (a rejection);
- inserted: the phrase comes out, and a spurious phrase after it (a false accept).

Text outside the vocabulary is rejected, as a grammar engine would. Each result comes
`latency_s` (+- `latency_jitter_s`, uniform) after the teacher stopped speaking. Seeded: the
same seed and inputs give the same results.
"""

from __future__ import annotations

import random
from collections import Counter
from dataclasses import dataclass
from typing import Literal

from voxshape.protocol.vocabulary import Vocabulary, normalize, written_phrases
from voxshape.runtime.settings import option

ErrorKind = Literal["misheard", "dropped", "inserted"]
ERROR_KINDS: tuple[ErrorKind, ...] = ("misheard", "dropped", "inserted")
MOCK = "mock engine"  # its flags' group in `voxshape speech --help`


@dataclass(frozen=True)
class MockSettings:
    """The flags are the speech service's (`voxshape speech --engine mock`)."""

    error_rate: float = option(0.0, "0..1 of utterances", group=MOCK)
    misheard: float = 0.6  # relative weights of the kinds of error
    dropped: float = 0.3
    inserted: float = 0.1
    latency_s: float = option(0.3, "seconds after the speech", flag="--latency", group=MOCK)
    latency_jitter_s: float = option(
        0.0, "+- seconds, uniform", flag="--latency-jitter", group=MOCK
    )
    seed: int | None = option(None, "random seed", group=MOCK)

    def __post_init__(self) -> None:
        if not 0.0 <= self.error_rate <= 1.0:
            raise ValueError(f"error rate {self.error_rate} is not within [0, 1]")
        weights = (self.misheard, self.dropped, self.inserted)
        if min(weights) < 0 or sum(weights) <= 0:
            raise ValueError("confusion weights must be >= 0 and not all 0")
        if self.latency_s < 0 or self.latency_jitter_s < 0:
            raise ValueError("latency and jitter must be >= 0 seconds")
        if self.latency_jitter_s > self.latency_s:
            raise ValueError("latency jitter cannot exceed the latency (no negative delays)")


@dataclass(frozen=True)
class Heard:
    text: str  # a vocabulary phrase as written
    confidence: float
    delay_s: float  # after the end of speech
    error: ErrorKind | None = None  # None: recognized as said


class MockRecognizer:
    engine = "mock"

    def __init__(self, vocabulary: Vocabulary, settings: MockSettings | None = None) -> None:
        self.settings = settings or MockSettings()
        self.counters: Counter[str] = Counter()
        self._written = {lang: written_phrases(vocabulary, lang) for lang in vocabulary.languages}
        self._rng = random.Random(self.settings.seed)

    def hear(self, text: str, language: str, key: str | None = None) -> list[Heard]:
        """What the mock recognizes of `text` said in `language`: zero, one or two phrases.
        With a `key` (the said message's id) the draw depends on it alone, as an engine hears
        the same audio the same way: a restarted service hears a recovered message as before."""
        s = self.settings
        rng = self._rng if key is None else random.Random(f"{s.seed}|{key}")
        written = self._written.get(language, {})
        phrase = written.get(normalize(text))
        if phrase is None:
            self.counters["mock.out_of_vocabulary"] += 1
            return []
        if rng.random() >= s.error_rate:
            self.counters["mock.correct"] += 1
            return [Heard(phrase, rng.uniform(0.75, 1.0), self._delay(rng))]
        kind = rng.choices(ERROR_KINDS, weights=(s.misheard, s.dropped, s.inserted))[0]
        self.counters[f"mock.{kind}"] += 1
        others = [p for key, p in written.items() if key != normalize(text)]
        if kind == "dropped" or not others:
            return []
        wrong = rng.choice(others)
        if kind == "misheard":
            return [Heard(wrong, rng.uniform(0.4, 0.9), self._delay(rng), "misheard")]
        first = Heard(phrase, rng.uniform(0.75, 1.0), self._delay(rng))
        extra = Heard(wrong, rng.uniform(0.3, 0.8), first.delay_s + 0.2, "inserted")
        return [first, extra]

    def _delay(self, rng: random.Random) -> float:
        s = self.settings
        return max(0.0, s.latency_s + rng.uniform(-s.latency_jitter_s, s.latency_jitter_s))

"""cascade, the default engine: pocketsphinx first, Whisper on what it is not sure of.

pocketsphinx is cheap (a real-time factor of about 0.03) but deaf to some voices and words;
Whisper scores the vocabulary far better at several times the cost. So every utterance
goes to pocketsphinx, and its phrase is taken as it is when heard with `trust` confidence or
more; anything else (rejected, or heard with less) goes to Whisper with pocketsphinx's phrase
as a hint. When Whisper's likeliest phrase is the hint, the two engines agree and the phrase
is taken; otherwise Whisper's own verdict stands, its rejection included (whisper_engine.py).

Without Whisper (its packages not installed, or a --language the model cannot hear) the
cascade is pocketsphinx alone, said once at start by `missing`. `stats` counts the
utterances that reached Whisper and the CPU seconds each stage took.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from services.speech.pocketsphinx_engine import PRECISION_BY_POSTERIOR
from services.speech.recognizer import Recognition, Recognizer

if TYPE_CHECKING:
    from services.speech.whisper_engine import WhisperRecognizer

T = TypeVar("T")
SURE = PRECISION_BY_POSTERIOR[0][1]  # pocketsphinx's top calibrated confidence, 0.96


@dataclass
class CascadeStats:
    utterances: int = 0
    to_whisper: int = 0  # utterances pocketsphinx was not sure of
    cpu_s: dict[str, float] = field(default_factory=lambda: {"pocketsphinx": 0.0, "whisper": 0.0})


class CascadeRecognizer:
    engine = "cascade"

    def __init__(
        self,
        first: Recognizer,
        second: WhisperRecognizer | None,
        trust: float = SURE,
        missing: str = "",
    ) -> None:
        self.language = first.language
        self.first, self.second, self.trust = first, second, trust
        self.missing = missing  # why there is no second stage, when there is none
        self.stats = CascadeStats()
        # what the service says it is ready with
        self.distractor_count = getattr(first, "distractor_count", "-")
        self.unpronounceable = getattr(first, "unpronounceable", [])

    def recognize(self, samples: np.ndarray) -> Recognition | None:
        self.stats.utterances += 1
        heard = self._timed("pocketsphinx", self.first.recognize, samples)
        if self.second is None or (heard is not None and heard.confidence >= self.trust):
            return heard
        self.stats.to_whisper += 1
        hint = heard.text if heard is not None else None
        scored, something_else = self._timed("whisper", self.second.likeliest, samples, hint)
        if heard is not None and scored.text == heard.text:  # the two agree
            return Recognition(heard.text, max(heard.confidence, scored.confidence))
        return None if something_else else scored

    def _timed(self, stage: str, recognize: Callable[..., T], *args: object) -> T:
        start = time.process_time()
        try:
            return recognize(*args)
        finally:
            self.stats.cpu_s[stage] += time.process_time() - start

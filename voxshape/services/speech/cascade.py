"""cascade, the default engine: pocketsphinx and a phrase scorer (Whisper tiny.en, or
Moonshine with --scorer moonshine) decide together.

Every utterance goes to pocketsphinx, which is cheap (a real-time factor of about 0.03) and
gives a phrase with its lattice posterior, or none, then to the scorer with pocketsphinx's
phrase as a hint: the candidates are the scorer's likeliest phrase and pocketsphinx's, each
with what it won by over free speech, its sound-alikes (raw, and with the decoder's text
prior taken out) and the phrases of other meanings, whether the scorer's own transcript is
it, and whether pocketsphinx heard it; decision.choose weighs that into a confidence, and
the best candidate is heard from its fitted threshold when it also beats the phrases of the
other kind by the fitted margin. Otherwise a phrase spotted in a sentence of the scorer's
transcript ("could you go left") is heard, or nothing. (A phrase pocketsphinx was sure of
used to skip the scorer: it measured worse, docs/decisions.md.)

Without Whisper (its packages not installed, or a --language the model cannot hear) the
cascade is pocketsphinx alone, said once at start by `missing`. `stats` counts the
utterances that reached Whisper and the CPU seconds each stage took.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from voxshape.services.speech import decision
from voxshape.services.speech.recognizer import Recognition

if TYPE_CHECKING:
    from voxshape.services.speech.pocketsphinx_engine import PocketsphinxRecognizer
    from voxshape.services.speech.scorer import PhraseScorer, Scored

T = TypeVar("T")


@dataclass
class CascadeStats:
    utterances: int = 0
    to_whisper: int = 0  # utterances pocketsphinx did not decide alone
    cpu_s: dict[str, float] = field(default_factory=lambda: {"pocketsphinx": 0.0, "whisper": 0.0})


class CascadeRecognizer:
    engine = "cascade"

    def __init__(
        self,
        first: PocketsphinxRecognizer,
        second: PhraseScorer | None,
        missing: str = "",
    ) -> None:
        self.language = first.language
        self.first, self.second = first, second
        self.missing = missing  # why there is no second stage, when there is none
        scorer = second.engine if second is not None else "whisper"
        self.decision = decision.DECISIONS[f"cascade/{scorer}"]
        self.stats = CascadeStats()
        # what the service says it is ready with
        self.distractor_count = getattr(first, "distractor_count", "-")
        self.unpronounceable = getattr(first, "unpronounceable", [])

    def recognize(self, samples: np.ndarray) -> Recognition | None:
        self.stats.utterances += 1
        if self.second is None:
            return self._timed("pocketsphinx", self.first.recognize, samples)
        heard = self._timed("pocketsphinx", self.first.decode, samples)
        hint, posterior = heard if heard is not None else (None, 0.0)
        self.stats.to_whisper += 1
        scored = self._timed("whisper", self.second.likeliest, samples, hint)
        candidates = self.candidates(scored, hint, posterior)
        chosen = decision.choose(candidates, self.decision, self.second.kinds)
        if chosen is not None:
            return Recognition(*chosen)
        return self.second.spotted(scored, self.decision.accept)

    def candidates(
        self, scored: Scored, hint: str | None, posterior: float
    ) -> list[tuple[str, decision.Margins]]:
        """The scorer's likeliest phrase and pocketsphinx's, with what each won by."""
        assert self.second is not None
        out = []
        for phrase in sorted({scored.best(), hint} & set(scored.phrases)):
            margins = self.second.margins(scored, phrase)
            if phrase == hint:
                margins = replace(
                    margins, pocketsphinx_agrees=1.0, pocketsphinx_posterior=posterior
                )
            out.append((phrase, margins))
        return out

    def _timed(self, stage: str, recognize: Callable[..., T], *args: object) -> T:
        start = time.process_time()
        try:
            return recognize(*args)
        finally:
            self.stats.cpu_s[stage] += time.process_time() - start

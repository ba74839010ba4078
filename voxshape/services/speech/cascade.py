"""cascade, the default engine: pocketsphinx and Whisper decide together.

Every utterance goes to pocketsphinx, which is cheap (a real-time factor of about 0.03) and
gives a phrase with its lattice posterior, or none. A phrase it heard with a posterior of
`FAST` or more and that has no sound-alike ("perfect", "terrible", "forward") is taken as
it is. Everything else goes to Whisper with pocketsphinx's phrase as a hint: the candidates
are Whisper's likeliest phrase and pocketsphinx's, each with what it won by over free
speech, its sound-alikes and the phrases of other meanings, and whether pocketsphinx heard
it; decision.py weighs that into a confidence, and the best candidate is heard from
decision.ACCEPT. Otherwise a phrase spotted in a sentence of Whisper's transcript ("could
you go left") is heard, or nothing.

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
from voxshape.services.speech.pocketsphinx_engine import PRECISION_BY_POSTERIOR
from voxshape.services.speech.recognizer import Recognition

if TYPE_CHECKING:
    from voxshape.services.speech.pocketsphinx_engine import PocketsphinxRecognizer
    from voxshape.services.speech.scorer import PhraseScorer, Scored

T = TypeVar("T")
FAST, SURE = PRECISION_BY_POSTERIOR[0]  # posterior 0.75 and more: right 96% of the time


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
        sure = hint is not None and posterior >= FAST and not self.second.has_sound_alikes(hint)
        if sure and self.decision.fast:
            return Recognition(hint, SURE)  # type: ignore[arg-type]
        self.stats.to_whisper += 1
        scored = self._timed("whisper", self.second.likeliest, samples, hint)
        chosen = decision.choose(self.candidates(scored, hint, posterior), self.decision)
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

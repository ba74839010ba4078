"""How `voxshape speech` picks an engine (the interface: voxshape/services/speech/recognizer.py)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from voxshape.protocol.vocabulary import Vocabulary
from voxshape.services.speech.recognizer import (
    DEFAULT_SCORER,
    ENGINES,
    SCORERS,
    EngineError,
    Recognizer,
)

if TYPE_CHECKING:
    from voxshape.services.speech.pocketsphinx_engine import PocketsphinxSettings
    from voxshape.services.speech.scorer import PhraseScorer


def open_recognizer(
    engine: str,
    vocabulary: Vocabulary,
    language: str,
    model: Path | None = None,
    dictionary: Path | None = None,
    pocketsphinx_settings: PocketsphinxSettings | None = None,
    scorer: str = DEFAULT_SCORER,
    scorer_model: Path | None = None,
) -> Recognizer:
    """An audio engine ready to recognize; raises EngineError saying what is missing.
    The cascade's second stage is `scorer` (whisper or moonshine) with `scorer_model`."""
    if engine == "cascade":  # --model and --dictionary are pocketsphinx's
        from voxshape.services.speech.cascade import CascadeRecognizer

        first = open_recognizer(
            "pocketsphinx", vocabulary, language, model, dictionary, pocketsphinx_settings
        )
        try:
            second = open_scorer(scorer, vocabulary, language, scorer_model)
        except EngineError as e:
            return CascadeRecognizer(first, None, missing=str(e))
        return CascadeRecognizer(first, second)
    if engine == "pocketsphinx":
        from voxshape.services.speech.pocketsphinx_engine import PocketsphinxRecognizer

        return PocketsphinxRecognizer(
            vocabulary, language, pocketsphinx_settings, model=model, dictionary=dictionary
        )
    if engine == "vosk":
        from voxshape.services.speech.vosk_engine import VoskRecognizer

        return VoskRecognizer(vocabulary, language, model=model)
    if engine in SCORERS:
        return open_scorer(engine, vocabulary, language, model)
    raise EngineError(f"unknown audio engine {engine!r}; choose one of {', '.join(ENGINES)}")


def open_scorer(
    scorer: str, vocabulary: Vocabulary, language: str, model: Path | None = None
) -> PhraseScorer:
    """A phrase scorer (scorer.py): Whisper or Moonshine, from `model` or its default."""
    if scorer == "whisper":
        from voxshape.services.speech.whisper_engine import WhisperRecognizer

        return WhisperRecognizer(vocabulary, language, model=model)
    if scorer == "moonshine":
        from voxshape.services.speech.moonshine_engine import MoonshineRecognizer

        return MoonshineRecognizer(vocabulary, language, model=model)
    raise EngineError(f"unknown scorer {scorer!r}; choose one of {', '.join(SCORERS)}")

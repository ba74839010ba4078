"""How `voxshape speech` picks an engine (the interface: voxshape/services/speech/recognizer.py)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from voxshape.protocol.vocabulary import Vocabulary
from voxshape.services.speech.recognizer import ENGINES, EngineError, Recognizer

if TYPE_CHECKING:
    from voxshape.services.speech.pocketsphinx_engine import PocketsphinxSettings


def open_recognizer(
    engine: str,
    vocabulary: Vocabulary,
    language: str,
    model: Path | None = None,
    dictionary: Path | None = None,
    pocketsphinx_settings: PocketsphinxSettings | None = None,
) -> Recognizer:
    """An audio engine ready to recognize; raises EngineError saying what is missing."""
    if engine == "cascade":  # --model and --dictionary are pocketsphinx's
        from voxshape.services.speech.cascade import CascadeRecognizer
        from voxshape.services.speech.whisper_engine import WhisperRecognizer

        first = open_recognizer(
            "pocketsphinx", vocabulary, language, model, dictionary, pocketsphinx_settings
        )
        try:
            return CascadeRecognizer(first, WhisperRecognizer(vocabulary, language))
        except EngineError as e:
            return CascadeRecognizer(first, None, missing=str(e))
    if engine == "pocketsphinx":
        from voxshape.services.speech.pocketsphinx_engine import PocketsphinxRecognizer

        return PocketsphinxRecognizer(
            vocabulary, language, pocketsphinx_settings, model=model, dictionary=dictionary
        )
    if engine == "vosk":
        from voxshape.services.speech.vosk_engine import VoskRecognizer

        return VoskRecognizer(vocabulary, language, model=model)
    if engine == "whisper":
        from voxshape.services.speech.whisper_engine import WhisperRecognizer

        return WhisperRecognizer(vocabulary, language, model=model)
    raise EngineError(f"unknown audio engine {engine!r}; choose one of {', '.join(ENGINES)}")

"""The recognizer interface every engine implements.

A recognizer turns the audio of one endpointed utterance (int16 samples at 16 kHz, with a
little quiet around the speech) into one vocabulary phrase with a confidence, or None when it
heard nothing it knows (rejection). Every engine is restricted to the vocabulary: its text is
always a phrase of `voxshape/protocol/vocabulary.toml`, as written there.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from voxshape.protocol.vocabulary import written_phrases as written_phrases  # bench.py's

ENGINES = ("cascade", "pocketsphinx", "vosk", "whisper", "moonshine", "mock")
DEFAULT_ENGINE = "cascade"  # what `voxshape speech` runs unless told otherwise
SCORERS = ("whisper", "moonshine")  # the cascade's second stage (scorer.py)
DEFAULT_SCORER = "whisper"


class EngineError(RuntimeError):
    """The engine cannot run as configured; the message says what is missing and the fix."""


@dataclass(frozen=True)
class Recognition:
    text: str  # a vocabulary phrase, as written in the vocabulary
    confidence: float  # 0..1
    alternatives: tuple[tuple[str, float], ...] = ()  # other phrases and their confidence


class Recognizer(Protocol):
    engine: str
    language: str

    def recognize(self, samples: np.ndarray) -> Recognition | None:
        """The phrase heard in one utterance, or None (nothing of the vocabulary)."""
        ...

"""vosk: Kaldi models for many languages, restricted here to the vocabulary plus "[unk]".

No vosk model ships with voxshape and none can be downloaded on the project's machines: the
user provides one (`--model DIR` or VOSK_MODEL_PATH). `vosk.Model(lang=...)` is never called:
it reaches for the internet and can exit the process.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from protocol.messages import SAMPLE_RATE
from protocol.vocabulary import Vocabulary, normalize
from services.speech.engines import EngineError, Recognition, written_phrases

MODELS_URL = "https://alphacephei.com/vosk/models"
SMALL_MODELS = {"en": "vosk-model-small-en-us-0.15", "es": "vosk-model-small-es-0.42"}


def missing_model_help(problem: str, language: str) -> str:
    small = SMALL_MODELS.get(language, SMALL_MODELS["en"])
    return (
        f"vosk needs a model directory: {problem}. No vosk model ships with voxshape and none "
        f"can be downloaded from here: get one from {MODELS_URL} (the small English model is "
        f"{SMALL_MODELS['en']}, the small Spanish one {SMALL_MODELS['es']}), unzip it, and "
        f"point the service at the folder: `voxshape speech --engine vosk --language {language} "
        f"--model /path/to/{small}` or VOSK_MODEL_PATH=/path/to/{small}. Without a model, "
        "`--engine pocketsphinx` recognizes English offline."
    )


def model_folder(model: Path | None, language: str, env: Mapping[str, str] = os.environ) -> Path:
    """The configured model folder, checked; raises EngineError naming what is wrong."""
    raw = model or env.get("VOSK_MODEL_PATH")
    if not raw:
        raise EngineError(missing_model_help("none is configured", language))
    path = Path(raw)
    if not path.is_dir():
        raise EngineError(missing_model_help(f"{str(path)!r} is not a directory", language))
    if not any((path / p).is_file() for p in ("am/final.mdl", "final.mdl")):
        raise EngineError(
            missing_model_help(f"{str(path)!r} holds no vosk model (no am/final.mdl)", language)
        )
    return path


class VoskRecognizer:
    engine = "vosk"

    def __init__(
        self,
        vocabulary: Vocabulary,
        language: str = "en",
        model: Path | None = None,
        env: Mapping[str, str] = os.environ,
    ) -> None:
        path = model_folder(model, language, env)
        import vosk

        vosk.SetLogLevel(-1)
        try:
            self._model = vosk.Model(model_path=str(path))
        except Exception as e:  # vosk raises a bare Exception("Failed to create a model")
            problem = f"{str(path)!r} failed to load ({e})"
            raise EngineError(missing_model_help(problem, language)) from None
        self._vosk = vosk
        self.language = language
        self._written = written_phrases(vocabulary, language)
        # vosk's words keep their accents ("atrás"): the grammar uses the phrases as written
        grammar = [*sorted({p.casefold() for p in self._written.values()}), "[unk]"]
        self._grammar = json.dumps(grammar, ensure_ascii=False)

    def recognize(self, samples: np.ndarray) -> Recognition | None:
        recognizer = self._vosk.KaldiRecognizer(self._model, SAMPLE_RATE, self._grammar)
        recognizer.SetWords(True)
        pcm = np.asarray(samples, dtype="<i2").tobytes()
        for i in range(0, len(pcm), 8000):  # fed as a stream, in quarter seconds
            recognizer.AcceptWaveform(pcm[i : i + 8000])
        result = json.loads(recognizer.FinalResult())
        text = result.get("text", "")
        if not text or "[unk]" in text:
            return None
        phrase = self._written.get(normalize(text))
        if phrase is None:
            return None
        words = result.get("result") or []
        confidence = min((float(w.get("conf", 1.0)) for w in words), default=1.0)
        return Recognition(phrase, max(0.0, min(1.0, confidence)))

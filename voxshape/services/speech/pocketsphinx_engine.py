"""pocketsphinx: the offline engine (its wheel bundles a US-English model).

A finite-state grammar of the vocabulary's phrases, plus rejection: the same grammar offers
a sample of other dictionary words ("distractors") as competing paths, so speech outside the
vocabulary is matched by a distractor, or by no complete phrase, and rejected. Distractors
are at least `distractor_min_distance` phone edits from every vocabulary word, so a
vocabulary word is not lost to its own near-homophones. Tried on synthesized
speech while building this (one-off scripts, not kept): keyword spotting with per-phrase
thresholds, a free phone loop as garbage path, and score ratios against a phone decoder all
rejected worse at the same accuracy; the phone loop was also 2-7x slower. The trade-off of
the number of distractors is measured by `python -m benchmarks.speech` (docs/speech.md#accuracy).

The confidence is calibrated. The lattice posterior of the phrase hardly tells right from
wrong: the arbiter's gate of 0.5 dropped 27 phrases of the tuning split's vocabulary speech,
22 of them right, and the clean accuracy a teacher meets fell from 0.786 to 0.726.
So the posterior is mapped to the share of phrases recognized right at that posterior on the
tuning split (`PRECISION_BY_POSTERIOR`; `python -m benchmarks.speech --raw-confidence --split tune`
prints the table). Rejection stays the distractors' job.

Digital silence (exact zeros, as synthesized or gated audio has) derails pocketsphinx's
feature normalization: recognition of the fixtures fell from 85% to 51% with it. A seeded
noise floor (`noise_floor`, std dev in int16 units, about -60 dBFS) like a real microphone's is
added before decoding.
"""

from __future__ import annotations

import random
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from voxshape.protocol.vocabulary import Vocabulary, normalize, written_phrases
from voxshape.runtime.settings import option
from voxshape.services.speech import spanish
from voxshape.services.speech.recognizer import EngineError, Recognition
from voxshape.services.speech.sound_alikes import read_dictionary

MODEL_HINT = (
    "pocketsphinx ships only a US-English model (Spanish is heard with it, its words spelt in "
    "English phones): another language needs a CMU Sphinx acoustic model and dictionary, "
    "given with --model DIR --dictionary FILE; or use --engine vosk with a vosk model"
)
SPANISH_SUFFIX = "-es"  # a Spanish word's name in the English dictionary ("no-es", not "no")


# Distractors by language (measured: docs/speech.md#accuracy): Spanish words spelt in English
# phones match their speech less well than English words theirs, so fewer compete.
DISTRACTORS = {"en": 1000, "es": 600}
REJECTION = "pocketsphinx rejection of words outside the vocabulary"  # its flags' group
# (posterior from, share right): English tuning split, 181/188 from 0.75, 41/51 below
PRECISION_BY_POSTERIOR = ((0.75, 0.96), (0.0, 0.80))


@dataclass(frozen=True)
class PocketsphinxSettings:
    # dictionary words competing with the vocabulary (0: no rejection; None: DISTRACTORS')
    distractors: int | None = option(
        None,
        "dictionary words competing with the vocabulary (0: no rejection; more rejects more "
        "and loses more of the vocabulary; docs/speech.md#accuracy)",
        show="by language: " + ", ".join(f"{lang} {n}" for lang, n in DISTRACTORS.items()),
        group=REJECTION,
    )
    distractor_weight: float = option(
        1e-4, "their total prior against the vocabulary's 1", group=REJECTION
    )
    distractor_min_distance: int = 2  # phone edits from any vocabulary word, at least
    distractor_max_phones: int = 6
    noise_floor: float = 30.0
    seed: int = 0
    calibrated: bool = True  # confidence: the measured share right, not the posterior


def phone_distance(a: tuple[str, ...], b: tuple[str, ...]) -> int:
    """Levenshtein distance between two phone sequences."""
    previous = list(range(len(b) + 1))
    for i, x in enumerate(a, 1):
        current = [i]
        for j, y in enumerate(b, 1):
            current.append(min(previous[j] + 1, current[j - 1] + 1, previous[j - 1] + (x != y)))
        previous = current
    return previous[-1]


class PocketsphinxRecognizer:
    engine = "pocketsphinx"

    def __init__(
        self,
        vocabulary: Vocabulary,
        language: str = "en",
        settings: PocketsphinxSettings | None = None,
        model: Path | None = None,
        dictionary: Path | None = None,
    ) -> None:
        import pocketsphinx

        self.language = language
        self.settings = settings or PocketsphinxSettings()
        by_rule = language == "es" and model is None and dictionary is None
        if language not in ("en", "es") and (model is None or dictionary is None):
            raise EngineError(f"no pocketsphinx model for {language!r}: {MODEL_HINT}")
        for what, path in (("model", model), ("dictionary", dictionary)):
            if path is not None and not Path(path).exists():
                raise EngineError(f"pocketsphinx {what} {str(path)!r} does not exist")
        hmm = str(model) if model else pocketsphinx.get_model_path("en-us/en-us")
        dict_path = Path(dictionary or pocketsphinx.get_model_path("en-us/cmudict-en-us.dict"))
        try:
            self._decoder = pocketsphinx.Decoder(
                hmm=hmm, dict=str(dict_path), lm=None, loglevel="FATAL", bestpath=True
            )
        except (RuntimeError, ValueError) as e:
            raise EngineError(f"pocketsphinx cannot load model {hmm!r}: {e}") from None
        lexicon = read_dictionary(dict_path)
        self._spanish: dict[str, list[tuple[str, ...]]] = defaultdict(list)
        self.unpronounceable: list[str] = []  # phrases left out: a word has no pronunciation
        self._phrases: dict[tuple[str, ...], str] = {}
        for key, written in written_phrases(vocabulary, language).items():
            if by_rule:  # Spanish words by rule, under names of their own
                for said in spanish.spoken_forms(key):
                    self._phrases[tuple(self._add_spanish(w) for w in said)] = written
                continue
            words = tuple(key.split())
            if all(self._ensure_word(w, written, lexicon) for w in words):
                self._phrases[words] = written
            else:
                self.unpronounceable.append(written)
        if not self._phrases:
            raise EngineError(f"no {language} phrase of the vocabulary can be pronounced")
        vocabulary_words = {w for words in self._phrases for w in words}
        distractors = self._distractors(lexicon, vocabulary_words)
        self._decoder.add_fsg("voxshape", self._grammar(distractors))
        self._decoder.activate_search("voxshape")
        self.distractor_count = len(distractors)

    # -- the grammar ----------------------------------------------------------------------
    def _ensure_word(self, word: str, phrase: str, lexicon: dict) -> bool:
        """Puts `word` (normalized) in the decoder's dictionary; the written spelling's
        pronunciation serves when the normalized one is missing ("thats" <- "that's")."""
        if self._decoder.lookup_word(word) is not None:
            return True
        for token in phrase.casefold().split():
            if normalize(token) == word and token.strip(".,!?") in lexicon:
                self._decoder.add_word(word, " ".join(lexicon[token.strip(".,!?")][0]), True)
                return True
        return False

    def _add_spanish(self, word: str) -> str:
        """Puts a Spanish word in the decoder's dictionary with its pronunciations by rule;
        returns the name it has there."""
        name = word + SPANISH_SUFFIX
        if self._decoder.lookup_word(name) is None:
            for k, pron in enumerate(spanish.pronunciations(word), 1):
                self._decoder.add_word(name if k == 1 else f"{name}({k})", " ".join(pron), True)
                self._spanish[name].append(pron)
        return name

    def _distractors(self, lexicon: dict, vocabulary_words: set[str]) -> list[str]:
        s = self.settings
        wanted = DISTRACTORS.get(self.language, 1000) if s.distractors is None else s.distractors
        if wanted <= 0:
            return []
        # every pronunciation of a vocabulary word (all of them are in the decoder by now)
        spoken = {tuple(self._decoder.lookup_word(w).split()) for w in vocabulary_words}
        spoken |= {p for w in vocabulary_words for p in lexicon.get(w, [])}
        spoken |= {p for prons in self._spanish.values() for p in prons}
        candidates = sorted(
            w
            for w, prons in lexicon.items()
            if w.isascii()
            and w.isalpha()
            and w not in vocabulary_words
            and w + SPANISH_SUFFIX not in vocabulary_words  # English "final" for "final-es"
            and all(len(p) <= s.distractor_max_phones for p in prons)
        )
        random.Random(s.seed).shuffle(candidates)
        chosen = []
        far = s.distractor_min_distance
        for word in candidates:
            # lengths that differ by `far` or more are that many edits apart already
            if all(
                abs(len(p) - len(v)) >= far or phone_distance(p, v) >= far
                for p in lexicon[word]
                for v in spoken
            ):
                chosen.append(word)
                if len(chosen) == wanted:
                    break
        return chosen

    def _grammar(self, distractors: list[str]) -> object:
        start, final = 0, 1
        transitions: list[tuple] = []
        next_state = 2
        for words in self._phrases:
            state = start
            for i, word in enumerate(words):
                if i == len(words) - 1:
                    target = final
                else:
                    target, next_state = next_state, next_state + 1
                transitions.append(
                    (state, target, 1.0 / len(self._phrases) if i == 0 else 1.0, word)
                )
                state = target
        weight = self.settings.distractor_weight / max(1, len(distractors))
        transitions += [(start, final, weight, word) for word in distractors]
        return self._decoder.create_fsg("voxshape", start, final, transitions)

    # -- recognition ----------------------------------------------------------------------
    def recognize(self, samples: np.ndarray) -> Recognition | None:
        heard = self.decode(samples)
        if heard is None:
            return None
        phrase, posterior = heard
        if self.settings.calibrated:
            return Recognition(phrase, next(p for b, p in PRECISION_BY_POSTERIOR if posterior >= b))
        return Recognition(phrase, posterior)

    def decode(self, samples: np.ndarray) -> tuple[str, float] | None:
        """The phrase heard and its lattice posterior, or None (a distractor, or no
        complete phrase)."""
        audio = np.asarray(samples, dtype=np.float64)
        if self.settings.noise_floor > 0:
            rng = np.random.default_rng(self.settings.seed)
            audio = audio + rng.normal(0.0, self.settings.noise_floor, len(audio))
        pcm = np.clip(np.round(audio), -32768, 32767).astype("<i2").tobytes()
        decoder = self._decoder
        decoder.start_utt()
        decoder.process_raw(pcm, full_utt=True)
        decoder.end_utt()
        hypothesis = decoder.hyp()
        if hypothesis is None:
            return None
        phrase = self._phrases.get(tuple(hypothesis.hypstr.split()))
        if phrase is None:
            return None
        return phrase, float(min(1.0, max(0.0, decoder.get_prob())))

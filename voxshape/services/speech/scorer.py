"""Scoring the vocabulary's phrases against the audio with a speech-to-text decoder (Whisper
or Moonshine): the decoder's model is a `Backend`, what is done with it is `PhraseScorer`.

1. the audio is encoded once;
2. a free greedy decoding, capped at `FREE_TOKENS` tokens (`SENTENCE_TOKENS` when it is a
   sentence), gives its first token's distribution, the model's own transcript, and "free
   speech": the likeliest utterance along it that is no phrase, its first k tokens then an
   end (" Food" then "." for " Food, food");
3. each phrase is scored by forced decoding: log P(its tokens, then an end); only the phrases
   whose first token is among the `SHORTLIST` likeliest phrase starts are scored (and a phrase
   another engine heard, `hint`); the same decoding gives, where the phrase and each of its
   sound-alikes are one step apart (sound_alikes.py: " Good" against " Could"; "Go" then
   "al" against "Go" then the end), how much likelier the phrase's step is: the sound-alike
   margin, the smallest of these;
4. the same margin with the decoder's text prior taken out: minus the same difference under
   quiet (a lone "Go." is likelier text than "Goal." whatever was said), computed once at
   start (`sound_alike_prior`);
5. decision.py weighs what the best phrase won by into its confidence, heard from its
   rule's threshold (decision.choose); in a sentence ("Could you go left?") a phrase is
   spotted in the transcript.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from voxshape.protocol.messages import SAMPLE_RATE
from voxshape.protocol.vocabulary import NEGATIONS, Vocabulary, normalize, spot, written_phrases
from voxshape.services.speech import decision
from voxshape.services.speech.decision import Margins
from voxshape.services.speech.recognizer import Recognition
from voxshape.services.speech.sound_alikes import SoundAlikes, cmudict

FREE_TOKENS = 4  # models loop ("Stop stop stop..."): the free decoding is cut here
SENTENCE_TOKENS = 12  # ... or here, when its first tokens are words of a sentence
SHORTLIST = 4  # phrase first tokens scored (a phrase starting otherwise is not heard)
ENDS = (".", "!", "?", ",")  # with the end of text, what may follow a whole phrase
END = -1  # in a token sequence: the end (any of `ENDS` or the end of text)
QUIET_S = 1.0  # the quiet the text prior is measured on
QUIET_LEVEL = 8.0  # its noise (int16 units, about -72 dBFS)


class Backend(Protocol):
    """A speech-to-text decoder: tokens, and log-probabilities of the next token."""

    eot: int  # the end of text
    ends: list[int]  # the tokens that end a phrase: `eot` and those of `ENDS`
    stepwise: bool  # each decoder run is dear: fewer of them, batched (Moonshine)

    def tokens_of(self, text: str) -> list[int]: ...

    def text_of(self, tokens: list[int]) -> str: ...

    def encode(self, samples: np.ndarray) -> object:
        """The encoder's output for an utterance (int16 at 16 kHz)."""
        ...

    def greedy(self, encoded: object, prefix: list[int], n: int) -> tuple[list[int], np.ndarray]:
        """The greedy continuation of `prefix` (at most n tokens) and each step's log-probs."""
        ...

    def forced(self, encoded: object, sequences: list[list[int]]) -> list[np.ndarray]:
        """For each token sequence, the log-probs of every step: len(sequence) + 1 rows."""
        ...


@dataclass(frozen=True)
class Scored:
    """Scores of one utterance: log P of each phrase scored (then an end), each one's margin
    over its sound-alikes (raw, and with the text prior taken out), free speech's log P, and
    the transcript with the phrase it spots in it (its margin over its sound-alikes there)."""

    phrases: dict[str, float]
    sound_alike: dict[str, float]
    free: float
    transcript: str = ""
    spotted: tuple[str, float] | None = None
    sound_alike_prior: dict[str, float] | None = None

    def best(self) -> str:
        return max(self.phrases, key=self.phrases.__getitem__)

    def margins(
        self, phrase: str, meanings: dict[str, str], kinds: dict[str, str] | None = None
    ) -> Margins:
        """What `phrase` (one of those scored) won by; `meanings`: phrase -> meaning, `kinds`:
        phrase -> command or judgement (decision.kind_of)."""
        mine = self.phrases[phrase]
        others = [s for p, s in self.phrases.items() if meanings[p] != meanings[phrase]]
        rival = max(others, default=-np.inf)
        prior = (self.sound_alike_prior or {}).get(phrase, decision.MARGIN_CAP)
        kind = (kinds or {}).get(phrase)
        other = [s for p, s in self.phrases.items() if kind and kinds[p] != kind]  # type: ignore[index]
        return Margins(
            mine - self.free,
            self.sound_alike[phrase],
            mine - rival,
            prior=prior,
            other_kind=mine - max(other, default=-np.inf),
            transcribed=float(self.transcript == normalize(phrase)),
            words=float(len(phrase.split())),
        )


def first_unit(transcript: str) -> str:
    """A free transcript's first sentence, or the unit it repeats, normalized:
    " Go, go, go!" -> "go", "Left. Left." -> "left", " Go back." -> "go back"."""
    import re

    words = normalize(re.split(r"[.!?,;]", transcript.strip(), maxsplit=1)[0]).split()
    for n in range(1, len(words)):
        if words[n : 2 * n] == words[:n]:
            return " ".join(words[:n])
    return " ".join(words)


def one_step_apart(mine: list[int], theirs: list[int]) -> int | None:
    """Where two token sequences, each followed by an end, differ in one step that tells them
    apart: one token of the same place (" Good" / " Could", " Go left" / " Go lift"), or one
    ends where the other goes on ("Go" "." / "Go" "al"); None if they differ otherwise."""
    a, b = [*mine, END], [*theirs, END]
    k = next((k for k, (x, y) in enumerate(zip(a, b, strict=False)) if x != y), None)
    if k is None:
        return None
    same_length = len(a) == len(b) and a[k + 1 :] == b[k + 1 :]
    return k if same_length or END in (a[k], b[k]) else None


def log_softmax(logits: object) -> np.ndarray:
    """Log-probabilities of each row of a step-by-vocabulary array of logits."""
    rows = np.asarray(logits, dtype=np.float32)
    top = rows.max(axis=-1, keepdims=True)
    return rows - top - np.log(np.exp(rows - top).sum(axis=-1, keepdims=True))


class PhraseScorer:
    """An engine that scores the vocabulary's phrases with a decoder (`backend`); `lead` is
    what the decoder writes before a word (Whisper: a space)."""

    def __init__(
        self, vocabulary: Vocabulary, language: str, backend: Backend, engine: str, lead: str
    ) -> None:
        self.engine, self.language, self.backend, self.lead = engine, language, backend, lead
        self._phrases = written_phrases(vocabulary, language)  # normalized -> as written
        meanings = {w: vocabulary.lookup(w) for w in self._phrases.values()}
        self._meanings = {w: m.name for w, m in meanings.items() if m}
        self.kinds = {w: decision.kind_of(m.kind) for w, m in meanings.items() if m}
        # as the model writes a phrase said alone: " Go left"
        self._tokens = {w: self._tokens_of(w.capitalize()) for w in self._phrases.values()}
        self._sound_alikes = SoundAlikes(cmudict()) if language == "en" else None
        self._alikes: dict[tuple[str, tuple[int, ...]], list[tuple[int, int, int]]] = {}
        for phrase, tokens in self._tokens.items():  # sound-alikes per writing, built now
            self._alike_tokens(phrase, tokens)
        self.decision = decision.DECISIONS[engine]
        self._negations = [  # as single tokens: " No", " not"...
            t[0]
            for word in NEGATIONS
            for t in (self._tokens_of(word), self._tokens_of(word.capitalize()))
            if len(t) == 1
        ]
        self._prior = self._text_prior()

    def _tokens_of(self, text: str) -> list[int]:
        return self.backend.tokens_of(self.lead + text)

    def _text_prior(self) -> dict[str, list[float]]:
        """Each phrase's gaps over its sound-alikes under quiet: the decoder's text prior."""
        quiet = np.random.default_rng(0).normal(0.0, QUIET_LEVEL, int(QUIET_S * SAMPLE_RATE))
        encoded = self.backend.encode(quiet.astype(np.int16))
        phrases = list(self._tokens)
        rows = self.backend.forced(encoded, [self._tokens[p] for p in phrases])
        return {p: self._gaps(p, self._tokens[p], r) for p, r in zip(phrases, rows, strict=True)}

    def _alike_tokens(self, phrase: str, mine: list[int]) -> list[tuple[int, int, int]]:
        """(k, mine, theirs): where each of the phrase's sound-alikes, as the model writes it
        (capitalized alone, or inside a sentence, as `mine` is), is one step apart from it,
        and the two tokens there (END: the text ends)."""
        key = (phrase, tuple(mine))
        if key in self._alikes:
            return self._alikes[key]
        out, alikes = set(), self._sound_alikes
        capitalized = mine == self._tokens_of(phrase.capitalize())
        for text in alikes.of_phrase(tuple(phrase.casefold().split())) if alikes else ():
            if normalize(text) in self._phrases:
                continue  # a phrase of the vocabulary is scored as one
            theirs = self._tokens_of(text.capitalize() if capitalized else text)
            k = one_step_apart(mine, theirs)
            if k is not None:
                out.add((k, [*mine, END][k], [*theirs, END][k]))
        self._alikes[key] = sorted(out)
        return self._alikes[key]

    def has_sound_alikes(self, phrase: str) -> bool:
        return bool(self._alike_tokens(phrase, self._tokens[phrase]))

    def margins(self, scored: Scored, phrase: str) -> Margins:
        return scored.margins(phrase, self._meanings, self.kinds)

    def recognize(self, samples: np.ndarray) -> Recognition | None:
        """The best phrase when decision.choose hears it by this engine's rule, else a phrase
        spotted in a sentence, else None."""
        scored = self.likeliest(samples)
        best = scored.best()
        chosen = decision.choose([(best, self.margins(scored, best))], self.decision)
        if chosen is not None:
            return Recognition(*chosen)
        return self.spotted(scored, self.decision.accept)

    def spotted(self, scored: Scored, accept: float) -> Recognition | None:
        """The phrase spotted in a sentence of the transcript, when it beats its sound-alikes
        there by decision.SPOT_MARGIN; its confidence is the gate's least, `accept`."""
        if scored.spotted is None or scored.spotted[1] < decision.SPOT_MARGIN:
            return None
        return Recognition(scored.spotted[0], accept)

    def likeliest(self, samples: np.ndarray, hint: str | None = None) -> Scored:
        """The scores of the phrases likeliest to start the utterance (and `hint`, a phrase
        another engine heard), of free speech, and of the phrase spotted in a sentence."""
        encoded = self.backend.encode(samples)
        if self.backend.stepwise:
            first = self.backend.forced(encoded, [[]])[0]
        else:
            tokens, first = self._free(encoded)
        starts = sorted({t[0] for t in self._tokens.values()}, key=lambda t: -first[0, t])
        shortlist = [p for p, t in self._tokens.items() if t[0] in starts[:SHORTLIST]]
        if hint in self._tokens and hint not in shortlist:
            shortlist.append(hint)
        sequences = [self._tokens[p] for p in shortlist]
        if self.backend.stepwise:  # the free decoding's second step rides with the phrases
            *rows, two = self.backend.forced(encoded, [*sequences, [int(first[0].argmax())]])
            tokens, log_p = self._free(encoded, two)
        else:
            rows, log_p = self.backend.forced(encoded, sequences), first
        scores, alike, prior = {}, {}, {}
        for phrase, r in zip(shortlist, rows, strict=True):
            mine = self._tokens[phrase]
            said = sum(r[i, token] for i, token in enumerate(mine))
            scores[phrase] = float(said + self._log_p_end(r[len(mine)]))
            gaps = self._gaps(phrase, mine, r)
            alike[phrase] = min(gaps, default=decision.MARGIN_CAP)
            quiet = self._prior[phrase]
            prior[phrase] = min((g - q for g, q in zip(gaps, quiet, strict=True)), default=8.0)
        transcript = first_unit(self.backend.text_of(tokens))
        spotted = self._spot(transcript, tokens, log_p)
        return Scored(scores, alike, self._free_speech(tokens, log_p), transcript, spotted, prior)

    def _gaps(self, phrase: str, mine: list[int], log_p: np.ndarray) -> list[float]:
        """log P(the phrase's token) - log P(a sound-alike's), where they first differ, for
        each sound-alike; log_p: one row per token of the phrase, and one after it (without
        it, as in a sentence, the sound-alikes that differ in where the text ends are left
        out)."""
        return [
            float(self._value(log_p[k], a) - self._value(log_p[k], b))
            for k, a, b in self._alike_tokens(phrase, mine)
            if k < len(log_p)  # in a sentence: where the phrase's own tokens differ only
        ]

    def _value(self, row: np.ndarray, token: int) -> float:
        return self._log_p_end(row) if token == END else float(row[token])

    def _free(self, encoded: object, two: np.ndarray | None = None) -> tuple[list[int], np.ndarray]:
        """The free greedy decoding: its tokens and each step's log-probabilities;
        `SENTENCE_TOKENS` of them when its first ones are words of a sentence. `two`: its
        first two steps' rows, when known: a first token followed by an end is all of it
        ("God" then "."), else the decoding goes on from them."""
        if two is not None:
            first = int(two[0].argmax())
            if first == self.backend.eot:
                return [], two[:1]
            if int(two[1].argmax()) in self.backend.ends:
                return [first], two
            tokens, log_p = self.backend.greedy(encoded, [first], FREE_TOKENS)
        else:
            tokens, log_p = self.backend.greedy(encoded, [], FREE_TOKENS)
        said = first_unit(self.backend.text_of(tokens))
        if len(tokens) >= FREE_TOKENS and len(said.split()) >= 2 and not self._begins(said):
            tokens, log_p = self.backend.greedy(encoded, tokens, SENTENCE_TOKENS)
        return tokens, log_p

    def _begins(self, said: str) -> bool:
        """Whether words are the beginning of a phrase, or a whole one ("turn to your")."""
        return any(f"{p} ".startswith(f"{said} ") for p in self._phrases)

    def _free_speech(self, tokens: list[int], log_p: np.ndarray) -> float:
        """log P of the likeliest utterance along the free decoding that is no phrase: its
        first k tokens then an end, for the best k ("Go" then "." for "Go, go, go")."""
        said, other = 0.0, -np.inf
        for k in range(1, min(len(tokens), len(log_p) - 1, FREE_TOKENS) + 1):
            said += log_p[k - 1, tokens[k - 1]]
            if first_unit(self.backend.text_of(tokens[:k])) not in self._phrases:
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
        for form in (phrase, phrase.capitalize()):
            mine = self._tokens_of(form)
            for at in range(len(tokens) - len(mine) + 1):
                if tokens[at : at + len(mine)] == mine and at + len(mine) <= len(log_p):
                    if at > 0 and self._maybe_negation(log_p[at - 1], tokens[at - 1]):
                        return None
                    rows = log_p[at : at + len(mine)]
                    return phrase, min(self._gaps(phrase, mine, rows), default=8.0)
        return None

    def _maybe_negation(self, log_p: np.ndarray, said: int) -> bool:
        """Whether the word before a phrase may have been a negation: one is within
        decision.NEGATION_DOUBT nats of the word written ("Now good" for "no good")."""
        return max(log_p[t] for t in self._negations) >= log_p[said] - decision.NEGATION_DOUBT

    def _log_p_end(self, log_p: np.ndarray) -> float:
        """log P(the utterance ends here), from one step's log-probabilities."""
        return float(np.logaddexp.reduce(log_p[self.backend.ends]))

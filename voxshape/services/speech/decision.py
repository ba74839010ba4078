"""The decision: is a phrase what was said, against everything else it could have been?

A phrase competes with three kinds of rival, each measured as a margin in nats (log-odds)
from the scorer's (Whisper's or Moonshine's) scores of the utterance:
- `free`: the scorer's own likeliest utterance that is no phrase ("something else": " Food.");
- `sound_alike`: the words one phone away from the phrase's ("could" for "good",
  voxshape/services/speech/sound_alikes.py), where they are one step apart; and `prior`, the
  same with the decoder's text prior taken out (a lone "Go." is likelier text than "Goal.");
- `other_phrase`: the likeliest phrase of another meaning ("bad" for "back");
with whether the scorer's own transcript is the phrase, how many words it has, and
pocketsphinx, a second ear, agreeing or not (with its lattice posterior).

They are weighed by a logistic model fitted on the tuning voices of every tuning family
(`python -m benchmarks.speech.fit`), so its output is the probability that the phrase is
right: the utterance's confidence. A phrase is heard when that is at least the rule's
`accept`, the lowest that lets at most 8% of the tuning near misses through, and when it
beats the likeliest phrase of the other kind (a command for a judgement, or the reverse) by
`kind_margin` nats: a judgement is never taken for a command on a close call
(docs/speech.md#accuracy).

Inside a sentence ("could you go left") a phrase is spotted in the scorer's transcript by the
rule typed words meet too (voxshape/protocol/vocabulary.py's `spot`), unless a negation comes
just before it ("no good", "not that way" being a phrase of its own), or may have: Whisper
writes "Now good." for some voices' "no good".
"""

from __future__ import annotations

import math
from dataclasses import astuple, dataclass

MARGIN_CAP = 8.0  # nats: beyond this a margin says no more
SPOT_MARGIN = 1.0  # nats over every sound-alike for a phrase spotted in a sentence
NEGATION_DOUBT = 3.0  # nats: a negation this near the word before a phrase may have been said


@dataclass(frozen=True)
class Margins:
    """What a phrase won by, in nats, and pocketsphinx's say (0/1, its posterior)."""

    free: float
    sound_alike: float
    other_phrase: float
    pocketsphinx_agrees: float = 0.0
    pocketsphinx_posterior: float = 0.0
    prior: float = MARGIN_CAP  # the sound-alike margin with the decoder's text prior out
    other_kind: float = MARGIN_CAP  # over the likeliest phrase of the other kind (not a feature)
    transcribed: float = 0.0  # 1: the scorer's own transcript is the phrase
    words: float = 1.0  # the phrase's

    def features(self) -> tuple[float, ...]:
        free, alike, other = (_cap(m) for m in astuple(self)[:3])
        return (free, alike, other, self.pocketsphinx_agrees, self.pocketsphinx_posterior,
                _cap(self.prior), self.transcribed, self.words)  # fmt: skip


def _cap(margin: float) -> float:
    return max(-MARGIN_CAP, min(MARGIN_CAP, margin))


def kind_of(kind: str) -> str:
    """ "command", or "judgement" (a qualifier, or the goal): the two kinds never to confuse."""
    return "command" if kind == "command" else "judgement"


@dataclass(frozen=True)
class DecisionRule:
    """One engine's fitted constants (`python -m benchmarks.speech.fit`)."""

    weights: tuple[float, ...]  # of Margins.features(), then the intercept
    accept: float  # the least confidence heard
    kind_margin: float = 0.0  # nats over the likeliest phrase of the other kind, at least


# fitted on the tuning voices of every tuning family (`python -m benchmarks.speech.fit`,
# docs/speech.md#the-decision-a-phrase-against-its-competitors): weights of
# Margins.features(), then the intercept; the threshold; the margin over the other kind
DECISIONS = {
    "cascade/whisper": DecisionRule(
        (0.17, 0.0, 0.183, 0.368, 1.058, 0.238, 0.194, 1.472, -3.519), 0.65, 2.0
    ),
    "whisper": DecisionRule((0.264, 0.104, 0.206, 0.0, 0.0, 0.0, -0.189, 1.239, -3.287), 0.73, 2.0),
    "cascade/moonshine": DecisionRule(
        (0.176, -0.017, 0.302, 1.696, -0.364, 0.171, 0.506, 1.444, -5.16), 0.65, 2.0
    ),
    "moonshine": DecisionRule(
        (0.234, -0.006, 0.398, 0.0, 0.0, 0.149, 0.061, 1.857, -5.613), 0.62, 2.0
    ),
}


def choose(
    candidates: list[tuple[str, Margins]], d: DecisionRule, kinds: dict[str, str] | None = None
) -> tuple[str, float] | None:
    """The candidate with the highest confidence, when it reaches `d.accept`, beats every
    phrase of the other kind (a command for a judgement, or the reverse) by `d.kind_margin`,
    and pocketsphinx did not hear a phrase of the other kind (`kinds`: phrase -> kind_of)."""
    if not candidates:
        return None
    scored = [(confidence(m, d.weights), p, m) for p, m in candidates]
    heard, phrase, margins = max(scored, key=lambda c: c[0])
    kind = (kinds or {}).get(phrase)
    if any(m.pocketsphinx_agrees and kind != (kinds or {}).get(p) for p, m in candidates):
        return None  # the two ears disagree on the kind: a close call, refused
    if heard >= d.accept and margins.other_kind >= d.kind_margin:
        return phrase, heard
    return None


def confidence(margins: Margins, weights: tuple[float, ...]) -> float:
    """The probability that the phrase is right, by the fitted logistic model."""
    *w, bias = weights
    z = bias + sum(a * x for a, x in zip(w, margins.features(), strict=True))
    return 1.0 / (1.0 + math.exp(-z))

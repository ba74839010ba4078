"""The decision: is a phrase what was said, against everything else it could have been?

A phrase competes with three kinds of rival, each measured as a margin in nats (log-odds)
from Whisper's scores of the utterance:
- `free`: Whisper's own likeliest utterance that is no phrase ("something else": " Food.");
- `sound_alike`: the words one phone away from the phrase's ("could" for "good",
  voxshape/services/speech/sound_alikes.py), at the token where they differ;
- `other_phrase`: the likeliest phrase of another meaning ("bad" for "back");
and pocketsphinx, a second ear, agrees or not (with its lattice posterior).

The margins are weighed by a logistic model fitted on the benchmark's tuning split
(`python -m benchmarks.speech --fixtures DIR --fit-decision`, espeak-ng voices only), so its
output is the probability that the phrase is right: the utterance's confidence. A phrase is
heard when that is at least `ACCEPT`, chosen on the tuning split as the lowest that lets at
most 10% of the near misses through (docs/speech.md#accuracy).

Inside a sentence ("could you go left") a phrase is spotted in Whisper's transcript by the rule
typed words meet too (voxshape/protocol/vocabulary.py's `spot`), unless a negation comes just
before it ("no good", "not that way" being a phrase of its own), or may have: Whisper writes
"Now good." for some voices' "no good".
"""

from __future__ import annotations

import math
from dataclasses import astuple, dataclass

MARGIN_CAP = 8.0  # nats: beyond this a margin says no more
# fitted on the tuning split (`--fit-decision`): weights of the margins, then the intercept
WEIGHTS = {
    "cascade": (0.106, 0.186, 0.225, 1.894, 0.452, -1.888),
    "whisper": (0.205, 0.132, 0.201, 0.0, 0.0, -0.991),
}
ACCEPT = 0.7  # the least confidence heard: tuning split, near misses at most 10%
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

    def features(self) -> tuple[float, ...]:
        capped = (max(-MARGIN_CAP, min(MARGIN_CAP, m)) for m in astuple(self)[:3])
        return (*capped, self.pocketsphinx_agrees, self.pocketsphinx_posterior)


def confidence(margins: Margins, weights: tuple[float, ...]) -> float:
    """The probability that the phrase is right, by the fitted logistic model."""
    *w, bias = weights
    z = bias + sum(a * x for a, x in zip(w, margins.features(), strict=True))
    return 1.0 / (1.0 + math.exp(-z))

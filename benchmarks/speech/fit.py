"""Fits the decision (voxshape/services/speech/decision.py) on the tuning split: `--fit-decision`.

Each tuning clip goes through what the service does (quiet around, the segmenter), then
pocketsphinx and Whisper; each candidate phrase's margins are a row, labelled right when it
is the clip's phrase (a sentence's: a phrase of the meaning it credits). A logistic
regression on the rows gives the weights; the cascade's rows carry pocketsphinx's say, the
Whisper scorer's (its likeliest phrase only) do not. `ACCEPT` is then the lowest confidence,
on a grid of 0.05, at which the cascade lets at most `NEAR_MISSES` of the near misses pass.
Prints the constants to put in decision.py.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from benchmarks.speech import scoring
from voxshape.protocol import Vocabulary
from voxshape.protocol.messages import SAMPLE_RATE
from voxshape.runtime.audio import chunks
from voxshape.services.speech import decision
from voxshape.services.speech.cascade import FAST, CascadeRecognizer
from voxshape.services.speech.segmenter import Segmenter

NEAR_MISSES = 0.10  # the share of near misses the threshold may let through, at most
L2 = 0.01


@dataclass
class Rows:
    cascade: list[tuple[tuple[float, ...], bool]] = field(default_factory=list)
    whisper: list[tuple[tuple[float, ...], bool]] = field(default_factory=list)
    # per near-miss segment: the best candidate's features, or None (decided alone or none)
    near: list[list[tuple[float, ...]] | None] = field(default_factory=list)


def collect(clips: list[scoring.Clip], cascade: CascadeRecognizer, vocabulary: Vocabulary) -> Rows:
    """The margins of every candidate in the tuning clips' segments."""
    assert cascade.second is not None
    rows = Rows()
    for clip in clips:
        if clip.split != "tune" or clip.language != "en":
            continue
        for samples in _segments(clip):
            heard = cascade.first.decode(samples)
            hint, posterior = heard if heard else (None, 0.0)
            if hint and posterior >= FAST and not cascade.second.has_sound_alikes(hint):
                rows.near += [None] if clip.kind == "near" else []
                continue
            scored = cascade.second.likeliest(samples, hint)
            candidates = cascade.candidates(scored, hint, posterior)
            for phrase, margins in candidates:
                rows.cascade.append((margins.features(), _right(clip, phrase, vocabulary)))
            best = scored.best()
            plain = cascade.second.margins(scored, best).features()
            rows.whisper.append((plain, _right(clip, best, vocabulary)))
            if clip.kind == "near":
                rows.near.append([m.features() for _, m in candidates])
    return rows


def fit(rows: list[tuple[tuple[float, ...], bool]]) -> tuple[float, ...]:
    """Logistic regression by Newton's method, a little L2 on the weights."""
    x = np.array([r[0] for r in rows], dtype=float)
    y = np.array([r[1] for r in rows], dtype=float)
    x1 = np.hstack([x, np.ones((len(x), 1))])
    penalty = L2 * np.diag([*np.ones(x.shape[1]), 0.0])
    w = np.zeros(x1.shape[1])
    for _ in range(50):
        p = 1.0 / (1.0 + np.exp(-x1 @ w))
        gradient = x1.T @ (p - y) + penalty @ w
        hessian = x1.T @ (x1 * (p * (1 - p))[:, None]) + penalty
        w -= np.linalg.solve(hessian + 1e-9 * np.eye(len(w)), gradient)
    return tuple(round(float(v), 3) for v in w)


def threshold(near: list[list[tuple[float, ...]] | None], weights: tuple[float, ...]) -> float:
    """The lowest confidence on a grid of 0.05 at which at most NEAR_MISSES of the near
    misses pass (one decided by pocketsphinx alone passes at any)."""
    best = []
    for candidates in near:
        if candidates is None:
            best.append(1.0)
            continue
        margins = [decision.Margins(*f) for f in candidates]
        best.append(max((decision.confidence(m, weights) for m in margins), default=0.0))
    for accept in np.arange(0.5, 1.0, 0.05):
        if np.mean(np.array(best) >= accept) <= NEAR_MISSES:
            return round(float(accept), 2)
    return 0.95


def report(rows: Rows) -> str:
    cascade, whisper = fit(rows.cascade), fit(rows.whisper)
    return (
        f"{len(rows.cascade)} candidates (cascade), {len(rows.whisper)} (whisper), "
        f"{len(rows.near)} near-miss segments, on the tuning split:\n"
        f"WEIGHTS = {{'cascade': {cascade}, 'whisper': {whisper}}}\n"
        f"ACCEPT = {threshold(rows.near, cascade)}"
    )


def _right(clip: scoring.Clip, phrase: str, vocabulary: Vocabulary) -> bool:
    if clip.kind == "vocabulary":
        return phrase == clip.text
    meaning = vocabulary.lookup(phrase)
    return clip.kind == "sentence" and meaning is not None and meaning.name == clip.credits


def _segments(clip: scoring.Clip) -> list:
    samples, _ = scoring.as_stream(clip)
    segmenter = Segmenter()
    found = []
    for piece in chunks(samples, SAMPLE_RATE // 20):
        found += segmenter.feed(piece)
    return [s.samples for s in found + segmenter.flush()]

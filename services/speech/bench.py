"""Accuracy, false accepts and speed of the speech engines on WAV fixtures.

Each clip goes through what the service does with a teacher's stream: quiet before and after
it (a low noise floor, as a microphone has), the segmenter, then the recognizer on every
segment found. A vocabulary clip is correct when exactly one phrase was recognized and it is
the one spoken; `meaning_accuracy` also counts a phrase of the same meaning ("backwards" for
"backward"). An out-of-vocabulary clip is a false accept when anything was recognized.
"""

from __future__ import annotations

import csv
import time
from collections import defaultdict
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from protocol.messages import SAMPLE_RATE
from protocol.vocabulary import Vocabulary, normalize
from services.speech.audio import chunks, read_wav
from services.speech.engines import Recognizer
from services.speech.mock import MockRecognizer
from services.speech.segmenter import Segmenter, SegmenterConfig

QUIET_S = 0.5  # quiet around each clean clip
QUIET_NOISE = 8.0  # std dev of that quiet (int16 units, about -72 dBFS)


@dataclass(frozen=True)
class Clip:
    path: Path
    text: str
    language: str
    kind: str  # vocabulary, oov (unrelated words) or near (near misses of vocabulary words)
    voice: str
    noise: str
    snr_db: float
    speech_start_s: float
    speech_end_s: float

    @property
    def condition(self) -> str:
        return "clean" if self.noise == "none" else f"{self.noise} {self.snr_db:g} dB"


@dataclass
class Outcome:
    clip: Clip
    heard: list[str]
    onset_error_s: float | None  # first segment's onset minus the true speech start
    recognize_s: float
    audio_s: float


def load_clips(folder: Path) -> list[Clip]:
    """The clips listed in `folder/manifest.csv` (written by make_fixtures.py)."""
    with (folder / "manifest.csv").open(newline="") as f:
        return [
            Clip(
                path=folder / row["file"],
                text=row["text"],
                language=row["language"],
                kind=row["kind"],
                voice=row["voice"],
                noise=row["noise"],
                snr_db=float(row["snr_db"]),
                speech_start_s=float(row["speech_start_s"]),
                speech_end_s=float(row["speech_end_s"]),
            )
            for row in csv.DictReader(f)
        ]


def as_stream(clip: Clip, seed: int = 0) -> tuple[np.ndarray, float]:
    """The clip with quiet around it, as a teacher's stream would carry it; and where the
    clip starts in it (seconds). Noisy clips carry their own noise before and after."""
    samples = read_wav(clip.path)
    if clip.noise != "none":
        return samples, 0.0
    rng = np.random.default_rng(seed)
    quiet = int(QUIET_S * SAMPLE_RATE)
    padded = np.concatenate([np.zeros(quiet), samples, np.zeros(quiet)])
    padded = padded + rng.normal(0.0, QUIET_NOISE, len(padded))
    return np.clip(np.round(padded), -32768, 32767).astype(np.int16), QUIET_S


def transcribe_clip(
    clip: Clip, recognizer: Recognizer, segmenter_config: SegmenterConfig | None = None
) -> Outcome:
    samples, offset = as_stream(clip)
    segmenter = Segmenter(segmenter_config)
    segments = []
    for piece in chunks(samples, SAMPLE_RATE // 20):  # 50 ms chunks, as the teacher sends
        segments += segmenter.feed(piece)
    segments += segmenter.flush()
    heard, spent, audio = [], 0.0, 0.0
    for segment in segments:
        t0 = time.perf_counter()
        result = recognizer.recognize(segment.samples)
        spent += time.perf_counter() - t0
        audio += len(segment.samples) / SAMPLE_RATE
        if result is not None:
            heard.append(result.text)
    onset_error = (
        segments[0].start / SAMPLE_RATE - offset - clip.speech_start_s if segments else None
    )
    return Outcome(clip, heard, onset_error, spent, audio)


@dataclass
class Tally:
    n: int = 0
    correct: int = 0
    same_meaning: int = 0
    accepted: int = 0

    def add(self, correct: bool, same_meaning: bool, accepted: bool) -> None:
        self.n += 1
        self.correct += correct
        self.same_meaning += same_meaning
        self.accepted += accepted


@dataclass
class Report:
    engine: str
    language: str | None = None  # an audio engine's; None for the mock (each clip's own)
    outcomes: list[Outcome] = field(default_factory=list)

    def summary(self, vocabulary: Vocabulary) -> dict:
        groups: dict[str, Tally] = defaultdict(Tally)
        words: dict[str, Tally] = defaultdict(Tally)
        for o in self.outcomes:
            c = o.clip
            accepted = bool(o.heard)
            if self.language is not None and c.language != self.language:
                # speech in another language is outside this engine's vocabulary too
                groups[f"{c.language} speech to the {self.language} engine"].add(
                    False, False, accepted
                )
            elif c.kind == "vocabulary":
                correct = o.heard == [c.text] or [normalize(h) for h in o.heard] == [
                    normalize(c.text)
                ]
                meaning = len(o.heard) == 1 and (
                    vocabulary.lookup(o.heard[0]) is vocabulary.lookup(c.text)
                )
                keys = [f"{c.language} {c.condition}", f"{c.language} {c.condition} {c.voice}"]
                for key in keys:
                    groups[key].add(correct, meaning, accepted)
                words[f"{c.language}:{c.text}"].add(correct, meaning, accepted)
            else:
                for key in (f"oov {c.language}", f"oov {c.language} {c.kind}"):
                    groups[key].add(False, False, accepted)
        english_clean = groups.get("en clean", Tally())
        oov = [g for k, g in groups.items() if k.startswith("oov") and len(k.split()) == 2]
        oov_n = sum(g.n for g in oov)
        spent = sum(o.recognize_s for o in self.outcomes)
        audio = sum(o.audio_s for o in self.outcomes)
        onsets = [abs(o.onset_error_s) for o in self.outcomes if o.onset_error_s is not None]
        return {
            "engine": self.engine,
            "clips": len(self.outcomes),
            "accuracy": _ratio(english_clean.correct, english_clean.n),
            "meaning_accuracy": _ratio(english_clean.same_meaning, english_clean.n),
            "false_accept_rate": _ratio(sum(g.accepted for g in oov), oov_n),
            "realtime_factor": round(spent / audio, 4) if audio else None,
            "onset_error_p50_s": round(float(np.median(onsets)), 3) if onsets else None,
            "groups": {
                k: {
                    "n": g.n,
                    "accuracy": _ratio(g.correct, g.n),
                    "meaning_accuracy": _ratio(g.same_meaning, g.n),
                    "accept_rate": _ratio(g.accepted, g.n),
                }
                for k, g in sorted(groups.items())
            },
            "per_word_accuracy": {k: _ratio(t.correct, t.n) for k, t in sorted(words.items())},
        }


def _ratio(a: int, b: int) -> float | None:
    return round(a / b, 3) if b else None


def run(
    clips: Iterable[Clip],
    recognizer: Recognizer,
    progress: Callable[[Outcome], None] | None = None,
) -> Report:
    report = Report(recognizer.engine, recognizer.language)
    for clip in clips:
        outcome = transcribe_clip(clip, recognizer)
        report.outcomes.append(outcome)
        if progress:
            progress(outcome)
    return report


def run_mock(clips: Iterable[Clip], mock: MockRecognizer, repeats: int = 20) -> Report:
    """The mock on the clips' texts (it takes text, not audio), each said `repeats` times."""
    report = Report(mock.engine)
    for clip in list(clips) * repeats:
        heard = [h.text for h in mock.hear(clip.text, clip.language)]
        report.outcomes.append(Outcome(clip, heard, None, 0.0, 0.0))
    return report

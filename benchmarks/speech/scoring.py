"""Accuracy, false accepts and speed of the speech engines on WAV fixtures.

Each clip goes through what the service does with a teacher's stream: quiet before and after
it (a low noise floor, as a microphone has), the segmenter, then the recognizer on every
segment found, and the arbiter's confidence gate (`min_confidence`: a phrase heard with less
is not used, the teacher is asked to repeat). A vocabulary clip is correct when exactly one
phrase passed and it is the one spoken; `meaning_accuracy` also counts a phrase of the same
meaning ("backwards" for "backward"). A clip outside the engine's vocabulary is a false
accept when anything passed: unrelated words, near misses of vocabulary words, and speech
in another language than the engine's (unless heard as a phrase of the same meaning,
"excelente" for "excellent"). Each clip has a condition ("clean", "white 10 dB",
"telephone"...) and a split: "tune", what engine settings may be chosen on, or "held-out",
what they never are.
"""

from __future__ import annotations

import csv
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Container, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from voxshape.protocol.messages import MIN_CONFIDENCE, SAMPLE_RATE
from voxshape.protocol.vocabulary import Vocabulary, normalize
from voxshape.runtime.audio import chunks, read_wav
from voxshape.services.speech.decision import kind_of
from voxshape.services.speech.mock import MockRecognizer
from voxshape.services.speech.recognizer import Recognizer, written_phrases
from voxshape.services.speech.segmenter import Segmenter, SegmenterConfig

QUIET_S = 0.5  # quiet around each clean clip
QUIET_NOISE = 8.0  # std dev of that quiet (int16 units, about -72 dBFS)
SPLITS = ("tune", "held-out")
OUTSIDE = {"oov": "unrelated", "near": "near"}  # outside words by clip kind
OTHER_LANGUAGE = "other language"
SENTENCE = "sentence"  # sentences that credit nothing ("no good"), among the false accepts
CONFIDENCE_BANDS = (0.0, 0.5, 0.7, 0.8, 0.9, 0.95)  # lower bounds, for the reliability table


def noise_condition(noise: str, snr_db: float) -> str:
    """A clip's condition from its noise: "clean", or e.g. "white 10 dB"."""
    return "clean" if noise == "none" else f"{noise} {snr_db:g} dB"


@dataclass(frozen=True)
class Clip:
    path: Path
    text: str
    language: str
    kind: str  # vocabulary, oov (unrelated words), near (near misses) or sentence
    voice: str
    noise: str
    snr_db: float
    speech_start_s: float
    speech_end_s: float
    condition: str = "clean"  # "clean", "white 10 dB", "level -20 dBFS", "telephone"...
    split: str = "tune"  # or "held-out"
    credits: str = ""  # a sentence's: the meaning it credits ("": none, "no good")
    synthesizer: str = ""  # espeak-ng, festival...
    speed: int = 0  # the manifest's: benchmarks/speech/synthesize.py's percent of the voice's pace


@dataclass
class Outcome:
    clip: Clip
    heard: list[str]  # the phrases that passed the confidence gate
    onset_error_s: float | None  # first segment's onset minus the true speech start
    recognize_s: float
    audio_s: float
    latency_s: float | None = None  # end of speech to the last utterance heard
    recognized: list[tuple[str, float]] = field(default_factory=list)  # before the gate


def load_clips(folder: Path) -> list[Clip]:
    """The clips listed in `folder/manifest.csv` (written by make_fixtures.py). Manifests
    without condition and split (the committed ones) are clean or noisy, all "tune"."""
    with (folder / "manifest.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    clips = []
    for row in rows:
        noise, snr_db = row["noise"], float(row["snr_db"])
        clips.append(
            Clip(
                path=folder / row["file"],
                text=row["text"],
                language=row["language"],
                kind=row["kind"],
                voice=row["voice"],
                noise=noise,
                snr_db=snr_db,
                speech_start_s=float(row["speech_start_s"]),
                speech_end_s=float(row["speech_end_s"]),
                condition=row.get("condition") or noise_condition(noise, snr_db),
                split=row.get("split") or "tune",
                credits=row.get("credits") or "",
                synthesizer=row.get("synthesizer") or "",
                speed=int(float(row.get("speed") or 0)),
            )
        )
    return clips


def as_stream(clip: Clip, seed: int = 0) -> tuple[np.ndarray, float]:
    """The clip with quiet around it, as a teacher's stream would carry it; and where the
    clip starts in it (seconds). Noisy clips carry their own noise before and after; every
    other one (clean, level, telephone, reverb) gets the quiet."""
    samples = read_wav(clip.path)
    if clip.noise != "none":
        return samples, 0.0
    rng = np.random.default_rng(seed)
    quiet = int(QUIET_S * SAMPLE_RATE)
    padded = np.concatenate([np.zeros(quiet), samples, np.zeros(quiet)])
    padded = padded + rng.normal(0.0, QUIET_NOISE, len(padded))
    return np.clip(np.round(padded), -32768, 32767).astype(np.int16), QUIET_S


def transcribe_clip(
    clip: Clip,
    recognizer: Recognizer,
    segmenter_config: SegmenterConfig | None = None,
    min_confidence: float = MIN_CONFIDENCE,
) -> Outcome:
    samples, offset = as_stream(clip)
    segmenter = Segmenter(segmenter_config)
    step = SAMPLE_RATE // 20  # 50 ms chunks, as the teacher sends
    segments = []  # (segment, stream time when the segmenter gave it out)
    for i, piece in enumerate(chunks(samples, step)):
        at = min((i + 1) * step, len(samples)) / SAMPLE_RATE  # the end of this chunk
        segments += [(s, at) for s in segmenter.feed(piece)]
    segments += [(s, len(samples) / SAMPLE_RATE) for s in segmenter.flush()]
    heard, recognized, spent, audio, latency = [], [], 0.0, 0.0, None
    for segment, at in segments:
        t0 = time.perf_counter()
        result = recognizer.recognize(segment.samples)
        took = time.perf_counter() - t0
        spent += took
        audio += len(segment.samples) / SAMPLE_RATE
        if result is not None:
            recognized.append((result.text, result.confidence))
        if result is not None and result.confidence >= min_confidence:
            heard.append(result.text)
            latency = at + took - (offset + clip.speech_end_s)
    onset_error = (
        segments[0][0].start / SAMPLE_RATE - offset - clip.speech_start_s if segments else None
    )
    return Outcome(clip, heard, onset_error, spent, audio, latency, recognized)


@dataclass
class Tally:
    n: int = 0
    correct: int = 0
    same_meaning: int = 0
    accepted: int = 0
    confidence: float = 0.0  # summed, for the reliability table

    def add(self, correct: bool, same_meaning: bool, accepted: bool) -> None:
        self.n += 1
        self.correct += correct
        self.same_meaning += same_meaning
        self.accepted += accepted


def _by_key() -> defaultdict[Any, Tally]:
    """Tallies by key, each begun at its key's first count."""
    return defaultdict(Tally)


@dataclass
class _Tallies:
    """A report's outcomes counted the ways its summary states them."""

    conditions: dict[tuple[str, str, str], Tally] = field(default_factory=_by_key)
    voices: dict[tuple[str, str, str], Tally] = field(default_factory=_by_key)  # clean speech
    outside: dict[tuple[str, str], Tally] = field(default_factory=_by_key)  # (split, kind)
    words: dict[tuple[str, str, str], Tally] = field(default_factory=_by_key)  # (lang, text, split)
    bands: dict[tuple[str, float], Tally] = field(default_factory=_by_key)  # (split, confidence)
    sentences: dict[tuple[str, str], Tally] = field(default_factory=_by_key)  # (split, text)
    # (split, kind of word): what became of vocabulary speech (the mock's confusion model)
    confusion: dict[tuple[str, str], Counter] = field(default_factory=lambda: defaultdict(Counter))
    # (split, synthesizer, clean / near / unrelated / sentence): the engine's language only
    synthesizers: dict[tuple[str, str, str], Tally] = field(default_factory=_by_key)
    # (split, "said -> heard"): a judgement heard as a command or the reverse
    kind_pairs: Counter = field(default_factory=Counter)

    def count_confidences(self, o: Outcome, vocabulary: Vocabulary) -> None:
        """Each phrase recognized (before the gate) in its confidence band, right or not:
        the clip's phrase, or a sentence's meaning; anything from outside speech is wrong."""
        for text, confidence in o.recognized:
            band = max(b for b in CONFIDENCE_BANDS if confidence >= b)
            if o.clip.kind == "sentence":
                meaning = vocabulary.lookup(text)
                right = meaning is not None and meaning.name == o.clip.credits
            else:
                right = o.clip.kind == "vocabulary" and normalize(text) == normalize(o.clip.text)
            tally = self.bands[o.clip.split, band]
            tally.add(right, right, confidence >= MIN_CONFIDENCE)
            tally.confidence += confidence

    def count_other_language(self, o: Outcome, vocabulary: Vocabulary, own: Container[str]) -> None:
        """Speech in another language is outside the engine's vocabulary too; heard as a phrase
        of the same meaning ("excellent" as "excelente") it is right."""
        c = o.clip
        meant = vocabulary.lookup(c.text) if c.kind == "vocabulary" else None
        wrong = any(meant is None or vocabulary.lookup(h) is not meant for h in o.heard)
        if normalize(c.text) not in own:
            self.outside[c.split, OTHER_LANGUAGE].add(False, False, wrong)

    def count_sentence(self, o: Outcome, vocabulary: Vocabulary) -> None:
        """A sentence is right when it credits its meaning alone, or nothing when it credits
        none ("no good"); one that credits none and passes anything is a false accept."""
        c = o.clip
        meanings = [m.name if (m := vocabulary.lookup(h)) else h for h in o.heard]
        right = meanings == ([c.credits] if c.credits else [])
        self.sentences[c.split, c.text].add(right, right, bool(o.heard))
        self.synthesizers[c.split, c.synthesizer, SENTENCE].add(right, right, bool(o.heard))
        if not c.credits:
            self.outside[c.split, SENTENCE].add(False, False, bool(o.heard))

    def count_vocabulary(self, o: Outcome, vocabulary: Vocabulary) -> None:
        """A vocabulary clip: by condition, by voice when clean, by phrase."""
        c, accepted = o.clip, bool(o.heard)
        correct = [normalize(h) for h in o.heard] == [normalize(c.text)]
        meaning = len(o.heard) == 1 and vocabulary.lookup(o.heard[0]) is vocabulary.lookup(c.text)
        said = vocabulary.lookup(c.text)
        heard = [vocabulary.lookup(h) for h in o.heard]
        outcome = (
            "dropped" if not heard
            else "inserted" if len(heard) > 1
            else "right" if heard[0] is said
            else "misheard, same kind" if heard[0].kind == said.kind
            else "misheard, other kind"
        )  # fmt: skip
        self.confusion[c.split, said.kind][outcome] += 1
        for h, m in zip(o.heard, heard, strict=True):
            if m is not None and kind_of(m.kind) != kind_of(said.kind):
                self.kind_pairs[c.split, f"{c.text} -> {h}"] += 1
        self.conditions[c.split, c.language, c.condition].add(correct, meaning, accepted)
        if c.condition == "clean":
            self.voices[c.split, c.language, c.voice].add(correct, meaning, accepted)
            self.synthesizers[c.split, c.synthesizer, "clean"].add(correct, meaning, accepted)
        if c.split != "tune" or c.condition == "clean":
            self.words[c.language, c.text, c.split].add(correct, meaning, accepted)


@dataclass
class Report:
    engine: str
    language: str | None = None  # an audio engine's; None for the mock (each clip's own)
    outcomes: list[Outcome] = field(default_factory=list)

    def summary(self, vocabulary: Vocabulary) -> dict:
        """The headline figures (tune/held-out, clean, the engine's language; the mock's is
        English), then accuracy by split, language and condition, by voice on clean speech,
        false accepts by split and kind, accuracy per phrase, and the calibration: of the
        phrases recognized in vocabulary speech with a confidence in each band (before the
        gate), the share right."""
        tallies = self._count(vocabulary)
        language = self.language or "en"
        tune, held_out = (tallies.conditions.get((s, language, "clean"), Tally()) for s in SPLITS)
        rejected = {s: _sum(t for k, t in tallies.outside.items() if k[0] == s) for s in SPLITS}
        return {
            "engine": self.engine,
            "language": self.language,
            "clips": len(self.outcomes),
            "accuracy": _ratio(tune.correct, tune.n),
            "meaning_accuracy": _ratio(tune.same_meaning, tune.n),
            "held_out_accuracy": _ratio(held_out.correct, held_out.n),
            "held_out_meaning_accuracy": _ratio(held_out.same_meaning, held_out.n),
            "false_accept_rate": _ratio(rejected["tune"].accepted, rejected["tune"].n),
            "held_out_false_accept_rate": _ratio(
                rejected["held-out"].accepted, rejected["held-out"].n
            ),
            **self._speed(),
            "conditions": _nested(tallies.conditions),
            "voices": _nested(tallies.voices),
            "false_accepts": _false_accepts(tallies.outside),
            "calibration": _calibration(tallies.bands),
            "per_word_accuracy": _per_phrase(tallies.words),
            "sentences": _sentences(tallies.sentences),
            "synthesizers": _synthesizers(tallies.synthesizers),
            "kind_pairs": {
                split: {
                    pair: n for (s, pair), n in sorted(tallies.kind_pairs.items()) if s == split
                }
                for split in SPLITS
            },
            "confusion": {
                split: {
                    kind: dict(n)
                    for (s, kind), n in sorted(tallies.confusion.items())
                    if s == split
                }
                for split in SPLITS
            },
        }

    def _count(self, vocabulary: Vocabulary) -> _Tallies:
        """Every outcome counted: its recognized phrases by confidence (vocabulary speech in
        the engine's language), then the clip as vocabulary or as outside speech."""
        tallies = _Tallies()
        own = written_phrases(vocabulary, self.language) if self.language else {}
        language = self.language or "en"
        for o in self.outcomes:
            c = o.clip
            if c.language == language:
                tallies.count_confidences(o, vocabulary)
            if self.language is not None and c.language != self.language:
                tallies.count_other_language(o, vocabulary, own)
            elif c.kind == "vocabulary":
                tallies.count_vocabulary(o, vocabulary)
            elif c.kind == "sentence":
                tallies.count_sentence(o, vocabulary)
            else:
                kind = OUTSIDE.get(c.kind, c.kind)
                tallies.outside[c.split, kind].add(False, False, bool(o.heard))
                tallies.synthesizers[c.split, c.synthesizer, kind].add(False, False, bool(o.heard))
        return tallies

    def _speed(self) -> dict[str, float | None]:
        """The real-time factor, the segmenter's onset error and the latency (with how many
        utterances it is of)."""
        spent = sum(o.recognize_s for o in self.outcomes)
        audio = sum(o.audio_s for o in self.outcomes)
        onsets = [abs(o.onset_error_s) for o in self.outcomes if o.onset_error_s is not None]
        latencies = [o.latency_s for o in self.outcomes if o.latency_s is not None]
        return {
            "realtime_factor": round(spent / audio, 4) if audio else None,
            "onset_error_p50_s": _percentile(onsets, 50),
            "latency_p50_s": _percentile(latencies, 50),
            "latency_p95_s": _percentile(latencies, 95),
            "latency_n": len(latencies),
        }


def _false_accepts(outside: dict[tuple[str, str], Tally]) -> dict:
    """{split: {kind: figures}} of the speech outside the vocabulary."""
    return {
        split: {
            kind: {"n": t.n, "accepted": t.accepted, "rate": _ratio(t.accepted, t.n)}
            for (s, kind), t in sorted(outside.items())
            if s == split
        }
        for split in SPLITS
    }


def _calibration(bands: dict[tuple[str, float], Tally]) -> dict:
    """{split: {band: figures}}: of the phrases recognized in each band, the share right."""
    return {
        split: {
            f"{band:g}": {
                "n": t.n,
                "right": t.correct,
                "share": _ratio(t.correct, t.n),
                "confidence": round(t.confidence / t.n, 3) if t.n else None,
            }
            for (s, band), t in sorted(bands.items())
            if s == split
        }
        for split in SPLITS
    }


def _sentences(sentences: dict[tuple[str, str], Tally]) -> dict:
    """{split: {sentence: {"n", "right"}}}: each sentence credited as it should be."""
    out: dict = {split: {} for split in SPLITS}
    for (split, text), t in sorted(sentences.items()):
        out[split][text] = {"n": t.n, "right": t.correct}
    return out


def _synthesizers(tallies: dict[tuple[str, str, str], Tally]) -> dict:
    """{split: {synthesizer: {"clean": accuracy, "near": accepted share, ...}}}, the
    sentences' figure the share credited right."""
    out: dict = {split: {} for split in SPLITS}
    for (split, synthesizer, what), t in sorted(tallies.items()):
        share = t.correct if what in ("clean", SENTENCE) else t.accepted
        out[split].setdefault(synthesizer or "-", {})[what] = {
            "n": t.n,
            "share": _ratio(share, t.n),
        }
    return out


def _per_phrase(words: dict[tuple[str, str, str], Tally]) -> dict:
    """{"language:phrase": {split: accuracy}}."""
    return {
        f"{lang}:{text}": {split: _accuracy(words.get((lang, text, split))) for split in SPLITS}
        for lang, text in sorted({k[:2] for k in words})
    }


def _sum(tallies: Iterable[Tally]) -> Tally:
    total = Tally()
    for t in tallies:
        total.n, total.accepted = total.n + t.n, total.accepted + t.accepted
    return total


def _nested(tallies: dict[tuple[str, ...], Tally]) -> dict:
    """{(split, ..., name): tally} as {split: {...: {name: figures}}}, splits in order."""
    out: dict = {}
    for key in sorted(tallies, key=lambda k: (SPLITS.index(k[0]), k[1:])):
        t, node = tallies[key], out
        for part in key[:-1]:
            node = node.setdefault(part, {})
        node[key[-1]] = {
            "n": t.n,
            "accuracy": _ratio(t.correct, t.n),
            "meaning_accuracy": _ratio(t.same_meaning, t.n),
            "accept_rate": _ratio(t.accepted, t.n),
        }
    return out


def _accuracy(tally: Tally | None) -> float | None:
    return _ratio(tally.correct, tally.n) if tally else None


def _percentile(values: list[float], q: float) -> float | None:
    return round(float(np.percentile(values, q)), 3) if values else None


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

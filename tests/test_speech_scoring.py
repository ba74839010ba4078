"""The speech benchmark's scoring (benchmarks/speech): its plan of held-out voices, words and
conditions, latency from the end of speech, the arbiter's confidence gate, the summary."""

from __future__ import annotations

import dataclasses
import runpy
from pathlib import Path

from benchmarks.speech import scoring
from tests.test_speech import FIXTURES, VOCABULARY
from voxshape.protocol.messages import SAMPLE_RATE
from voxshape.services.speech.recognizer import Recognition

# every English voice of espeak-ng here (`espeak-ng --voices=en`, without mbrola's)
ESPEAK_ENGLISH = [
    "en-gb", "en-us", "en-gb-scotland", "en-gb-x-gbclan", "en-gb-x-rp", "en-gb-x-gbcwmd",
    "en-029", "en-us-nyc",
]  # fmt: skip


def test_the_full_plan_holds_out_voices_words_and_conditions():
    plan = runpy.run_path(str(FIXTURES / "make_fixtures.py"))["full_plan"]()
    tune = [c for c in plan if c.split == "tune"]
    held = [c for c in plan if c.split == "held-out"]
    assert len(tune) + len(held) == len(plan) and len({c.stem for c in plan}) == len(plan)
    # "good" in every English voice espeak-ng has
    espeak = [c for c in plan if c.synthesizer == "espeak-ng"]
    says_good = {c.voice.split("+")[0] for c in espeak if c.text == "good"}
    assert set(ESPEAK_ENGLISH) <= says_good
    # held-out speech of the vocabulary, clean: in voices tuning never hears
    held_voices = {c.voice for c in held if c.kind == "vocabulary" and c.condition == "clean"}
    assert held_voices and held_voices.isdisjoint({c.voice for c in tune})
    # settings are chosen on one synthesizer, and held out on the other whole
    assert {c.synthesizer for c in tune} == {"espeak-ng"}
    assert {c.synthesizer for c in held if c.condition != "clean"} >= {"festival", "espeak-ng"}
    kinds = {"vocabulary", "oov", "near", "sentence"}
    assert {c.kind for c in tune} == {c.kind for c in held} == kinds
    assert all(c.credits == "" or c.kind == "sentence" for c in plan)
    # outside words: none of the held-out ones is a tuning one
    outside = [c for c in plan if c.kind != "vocabulary"]
    tune_words = {c.text for c in outside if c.split == "tune"}
    assert tune_words.isdisjoint(c.text for c in outside if c.split == "held-out")
    assert {c.condition for c in tune} == {"clean", "white 10 dB", "pink 15 dB"}
    assert {c.condition for c in held} == {
        "clean", "level -10 dBFS", "level -20 dBFS", "level -30 dBFS", "telephone", "reverb"
    }  # fmt: skip
    for language in ("en", "es"):  # every phrase in both splits
        for split in (tune, held):
            spoken = {c.text for c in split if c.language == language}
            assert set(VOCABULARY.phrases(language)) <= spoken
    assert {c.kind for c in held if c.language == "es"} == {"vocabulary", "oov"}


def test_old_manifests_load_as_tuning_clips_with_conditions_from_their_noise():
    clips = scoring.load_clips(FIXTURES) + scoring.load_clips(FIXTURES / "ko")
    assert {c.split for c in clips} == {"tune"}
    assert {c.condition for c in clips} == {
        "clean", "white 10 dB", "white 15 dB", "pink 10 dB", "pink 15 dB"
    }  # fmt: skip
    assert all((c.condition == "clean") == (c.noise == "none") for c in clips)


class Says:
    """A recognizer that hears `text` in every segment."""

    engine, language = "stub", "en"

    def __init__(self, text: str | None) -> None:
        self.text = text

    def recognize(self, samples):
        return Recognition(self.text, 1.0) if self.text else None


def test_latency_runs_from_the_end_of_speech_and_conditions_get_quiet_around():
    clip = next(c for c in scoring.load_clips(FIXTURES) if c.path.name == "en-voc-good-en-us.wav")
    for condition in ("clean", "telephone", "reverb", "level -30 dBFS"):
        samples, offset = scoring.as_stream(dataclasses.replace(clip, condition=condition))
        assert offset == scoring.QUIET_S and len(samples) > 2 * scoring.QUIET_S * SAMPLE_RATE
    outcome = scoring.transcribe_clip(clip, Says("good"))
    assert outcome.heard == ["good"]
    # the segmenter waits out its hangover (0.3 s) before it gives the utterance out; the
    # recognizer's own wall-clock time is left out (a benchmark's figure, not a test's)
    assert 0.25 <= outcome.latency_s - outcome.recognize_s <= 0.45
    assert scoring.transcribe_clip(clip, Says(None)).latency_s is None


def test_the_benchmark_counts_what_passes_the_arbiters_confidence_gate():
    clip = next(c for c in scoring.load_clips(FIXTURES) if c.path.name == "en-voc-good-en-us.wav")

    class Unsure(Says):
        def recognize(self, samples):
            return Recognition(self.text, 0.3)

    outcome = scoring.transcribe_clip(clip, Unsure("good"))
    assert outcome.heard == [] and outcome.recognized == [("good", 0.3)]
    summary = scoring.Report("stub", "en", [outcome]).summary(VOCABULARY)
    assert summary["accuracy"] == 0.0
    assert summary["calibration"]["tune"] == {
        "0": {"n": 1, "right": 1, "share": 1.0, "confidence": 0.3}
    }


def test_the_summary_reports_each_split_condition_voice_and_false_accept():
    def outcome(text, heard, split="tune", condition="clean", voice="en-us", kind="vocabulary",
                language="en", latency=0.4):  # fmt: skip
        clip = scoring.Clip(
            Path("x.wav"), text, language, kind, voice, "none", 0.0, 0.0, 1.0, condition, split
        )
        return scoring.Outcome(clip, heard, 0.01, 0.01, 1.0, latency if heard else None)

    outcomes = [
        outcome("good", ["good"]),
        outcome("good", ["bad"]),
        outcome("backwards", ["backward"]),  # same meaning only
        outcome("good", ["good"], voice="en-gb+m3"),
        outcome("good", ["good"], split="held-out", voice="en-029", latency=0.6),
        outcome("left", [], split="held-out", voice="en-029"),
        outcome("left", ["left"], split="held-out", condition="reverb", latency=0.8),
        outcome("hello", ["good"], kind="oov"),
        outcome("goat", [], kind="near"),
        outcome("shop", [], kind="near", split="held-out"),
        outcome("bien", ["good"], language="es"),  # Spanish speech, heard with its meaning
        outcome("terrible", ["terrible"], language="es"),  # also English: not counted
        outcome("bien", ["left"], language="es", split="held-out"),  # another meaning: outside
    ]
    report = scoring.Report("stub", "en", outcomes)
    s = report.summary(VOCABULARY)
    assert (s["accuracy"], s["meaning_accuracy"]) == (0.5, 0.75)
    assert (s["held_out_accuracy"], s["held_out_meaning_accuracy"]) == (0.5, 0.5)
    assert (s["false_accept_rate"], s["held_out_false_accept_rate"]) == (0.333, 0.5)
    assert s["false_accepts"]["tune"] == {
        "near": {"n": 1, "accepted": 0, "rate": 0.0},
        "other language": {"n": 1, "accepted": 0, "rate": 0.0},
        "unrelated": {"n": 1, "accepted": 1, "rate": 1.0},
    }
    assert s["conditions"]["held-out"]["en"]["reverb"]["accuracy"] == 1.0
    assert s["voices"]["tune"]["en"]["en-gb+m3"]["n"] == 1
    assert "reverb" not in s["voices"]["held-out"]["en"]
    assert s["per_word_accuracy"]["en:good"] == {"tune": 0.667, "held-out": 1.0}
    assert s["per_word_accuracy"]["en:left"] == {"tune": None, "held-out": 0.5}
    assert s["latency_p50_s"] == 0.4 and 0.6 < s["latency_p95_s"] < 0.8  # of those heard
    # the Spanish engine's headline is Spanish
    spanish = scoring.Report("stub", "es", outcomes).summary(VOCABULARY)
    assert spanish["accuracy"] == 0.5 and spanish["held_out_accuracy"] == 0.0
    assert spanish["false_accepts"]["tune"]["other language"]["n"] == 6

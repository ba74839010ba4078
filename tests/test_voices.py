"""The benchmark's clip generator (benchmarks/speech/voices.py, synthesize.py): whole voices and
whole families held out, every near miss said by some voice, plans that would measure the wrong
thing refused, a family that is not installed skipped with what to install; and one clip made
end to end with espeak-ng, read back as the benchmark reads clips."""

from __future__ import annotations

import shutil

import pytest

from benchmarks.speech import scoring, synthesize
from benchmarks.speech import voices as v
from tests.test_speech import VOCABULARY

LEXICON = {
    "good": [("G", "UH", "D")],
    "could": [("K", "UH", "D")],
    "awful": [("AA", "F", "AH", "L")],
    "offal": [("AA", "F", "AH", "L")],
}


def near() -> list[str]:
    return v.near_misses(VOCABULARY, LEXICON)


def test_whole_families_and_whole_voices_are_held_out():
    split = {}
    for voice in v.VOICES:
        split.setdefault(voice.family, set()).add(voice.split)
    assert all(split[f] == {"held-out"} for f in v.UNTUNED)
    tuned = [f for f in split if f not in v.UNTUNED]
    assert tuned and all(split[f] == {"tune", "held-out"} for f in tuned)
    neural = {x.family for x in v.VOICES if x.neural}
    assert neural & set(v.UNTUNED) and neural - set(v.UNTUNED)  # one neural of each side
    clips = v.plan(VOCABULARY, near(), v.VOICES, "bench")
    by_voice = {(c.synthesizer, c.voice): c.split for c in clips}
    assert all(by_voice[(x.family, x.name)] == x.split for x in v.VOICES)


def test_every_near_miss_is_said_by_some_voice_and_names_are_unique():
    clips = v.plan(VOCABULARY, near(), v.VOICES, "bench")
    said = {c.text for c in clips if c.kind == "near"}
    assert said == set(near())
    assert len({c.stem for c in clips}) == len(clips)
    conditions = {c.condition for c in clips if c.synthesizer in v.UNTUNED}
    assert conditions == {"clean", *v.CONDITIONS}
    speeds = {c.speed for c in clips if c.synthesizer == "piper" and c.kind == "vocabulary"}
    assert speeds == {80, 100, 125, 150}


def test_a_near_miss_that_is_a_phrase_or_sounds_as_one_is_refused(monkeypatch):
    monkeypatch.setitem(v.NEAR, "awful", ["offal"])
    with pytest.raises(v.PlanError, match=r"homophones.*offal"):
        near()
    monkeypatch.setitem(v.NEAR, "awful", ["good"])
    with pytest.raises(v.PlanError, match=r"in the vocabulary.*good"):
        near()


def test_a_family_not_installed_is_skipped_saying_what_to_install(monkeypatch):
    monkeypatch.setattr(shutil, "which", lambda name: None)
    ready, absent = synthesize.installed_voices({"flite", "pico"})
    assert ready == [] and {x.family for x, _ in absent} == {"flite", "pico"}
    assert all("setup-voices.sh" in why for _, why in absent)
    piper = next(x for x in v.VOICES if x.family == "piper")
    monkeypatch.setattr(v.importlib.util, "find_spec", lambda name: None)
    assert "pip install -e '.[voices]'" in (v.missing(piper) or "")


def test_the_real_recordings_are_unrelated_words_only():
    clips = v.recorded_plan(VOCABULARY)
    known = {p.casefold() for p in VOCABULARY.phrases("en")}
    assert all(c.kind == "oov" and c.text not in known for c in clips)
    assert {"goodbye", "golf", "seven"} <= set(v.allison_words().values())


@pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="needs espeak-ng and sox")
def test_a_clip_is_made_and_read_back_as_the_benchmark_reads_it(tmp_path):
    clips = [
        v.PlannedClip("good", "en", "vocabulary", "espeak-ng", "en-us", 100),
        v.PlannedClip("could", "en", "near", "espeak-ng", "en-us", 100, condition="telephone"),
    ]
    made = synthesize.make(clips, tmp_path, jobs=1)
    assert [c.file for c in made] == [f"{c.stem}.wav" for c in clips]
    read = scoring.load_clips(tmp_path)
    assert [(c.text, c.kind, c.condition) for c in read] == [
        ("good", "vocabulary", "clean"),
        ("could", "near", "telephone"),
    ]
    assert all(0 < c.speech_start_s < c.speech_end_s for c in read)

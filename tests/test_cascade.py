"""The cascade, the default engine: pocketsphinx first, the Whisper scorer on what it is not
sure of. Its routing on stand-in stages (real Recognitions, no model), then the real engines
on committed clips, and `voxshape teach --wav` of the suite's "good" clip understood end to
end: teacher, speech service, arbiter and simulator over a router."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass, field

import numpy as np
import pytest

from benchmarks.speech import scoring
from protocol import Observation, robot_key
from services.runtime import Node
from services.speech.cascade import CascadeRecognizer
from services.speech.engines import open_recognizer
from services.speech.recognizer import Recognition
from tests.conftest import VOXSHAPE, bus_args, collect, wait_present
from tests.test_faults import paced_sim, service
from tests.test_speech import FIXTURES, VOCABULARY
from tests.test_whisper import needs_whisper

CLIPS = {c.path.name: c for c in scoring.load_clips(FIXTURES)}
AUDIO = np.zeros(16000, dtype=np.int16)


@dataclass
class First:
    """A first stage that hears what it is told to."""

    heard: Recognition | None
    language: str = "en"

    def recognize(self, samples: np.ndarray) -> Recognition | None:
        return self.heard


@dataclass
class Second:
    """A second stage whose likeliest phrase and verdict are given; it keeps its hints."""

    likeliest_phrase: Recognition
    something_else: bool
    hints: list[str | None] = field(default_factory=list)

    def likeliest(self, samples: np.ndarray, hint: str | None = None):
        self.hints.append(hint)
        return self.likeliest_phrase, self.something_else


def test_a_phrase_pocketsphinx_is_sure_of_never_reaches_whisper():
    whisper = Second(Recognition("left", 0.9), False)
    cascade = CascadeRecognizer(First(Recognition("good", 0.96)), whisper, trust=0.96)
    assert cascade.recognize(AUDIO) == Recognition("good", 0.96)
    assert whisper.hints == [] and cascade.stats.to_whisper == 0


def test_whisper_agreeing_with_pocketsphinx_takes_the_phrase_whatever_else_it_heard():
    whisper = Second(Recognition("goal", 0.3), something_else=True)
    cascade = CascadeRecognizer(First(Recognition("goal", 0.8)), whisper, trust=0.96)
    assert cascade.recognize(AUDIO) == Recognition("goal", 0.8)
    assert whisper.hints == ["goal"] and cascade.stats.to_whisper == 1


def test_otherwise_whispers_verdict_stands():
    disagrees = Second(Recognition("back", 0.7), something_else=False)
    cascade = CascadeRecognizer(First(Recognition("bad", 0.8)), disagrees)
    assert cascade.recognize(AUDIO) == Recognition("back", 0.7)
    refuses = Second(Recognition("good", 0.2), something_else=True)
    assert CascadeRecognizer(First(None), refuses).recognize(AUDIO) is None
    assert refuses.hints == [None]


def test_without_whisper_it_is_pocketsphinx_and_says_why(monkeypatch):
    monkeypatch.setitem(sys.modules, "ctranslate2", None)  # its import fails
    cascade = open_recognizer("cascade", VOCABULARY, "en")
    assert isinstance(cascade, CascadeRecognizer) and cascade.second is None
    assert "pip install -e '.[whisper]'" in cascade.missing
    clip = CLIPS["en-voc-turn-left-kal-diphone.wav"]
    assert scoring.transcribe_clip(clip, cascade).heard == ["turn left"]


@pytest.fixture(scope="module")
def cascade() -> CascadeRecognizer:
    recognizer = open_recognizer("cascade", VOCABULARY, "en")
    assert isinstance(recognizer, CascadeRecognizer) and recognizer.second is not None
    return recognizer


# Clips whose verdict is the same on every CPU: CTranslate2's int8 kernels differ by
# instruction set (AVX2, AVX-512, AVX, generic), and a clip whose phrase and "something else"
# are a few hundredths of a nat apart is heard on one and refused on another. The suite's
# "good" clip, streamed with quiet and noise around it, is one (-0.11 to +0.11 nats; its
# plain recording through `voxshape teach` below is heard at 0.94 on all four).
@needs_whisper
@pytest.mark.parametrize(
    "name",
    [
        "en-voc-wrong-kal-diphone.wav",  # pocketsphinx refuses it, Whisper hears it
        "en-voc-stop-en-us-klatt.wav",  # pocketsphinx unsure (0.80), Whisper agrees
        "en-voc-goal-en-us.wav",
        "en-voc-back-cmu-us-slt-arctic-hts.wav",
        "en-voc-terrible-kal-diphone.wav",
        "en-voc-forward-en-us-pink15db.wav",
    ],
)
def test_the_cascade_hears_the_vocabulary(cascade, name):
    outcome = scoring.transcribe_clip(CLIPS[name], cascade)
    assert outcome.heard == [CLIPS[name].text], outcome.recognized


@needs_whisper
@pytest.mark.parametrize(
    "name",
    [
        "en-nea-goat-en-us.wav",  # near misses: one sound from "goal", "right"
        "en-nea-light-en-us-klatt.wav",
        "en-oov-hello-en-us.wav",
        "en-oov-coffee-en-us-klatt.wav",
        "en-oov-okay-cmu-us-slt-arctic-hts.wav",
    ],
)
def test_the_cascade_refuses_what_is_not_in_the_vocabulary(cascade, name):
    assert scoring.transcribe_clip(CLIPS[name], cascade).heard == []


@needs_whisper
def test_the_suites_good_clip_is_understood_through_teach(
    spawn, router, session_id, client_config, tmp_path
):
    paced_sim(spawn, router, session_id)
    service(spawn, "arbiter", router, session_id, "arbiter", cwd=tmp_path)
    service(spawn, "speech", router, session_id, "speech", cwd=tmp_path)  # the default engine
    with Node("test", client_config("observer")) as node:  # every service up, the robot seen
        node.watch_presence()
        node.input("obs", robot_key(session_id, "r1", "obs"))
        wait_present(node, {"sim", "arbiter", "speech"}, timeout=60)
        collect(node, 1, Observation, timeout=30)
    wav = FIXTURES / "en-voc-good-en-us.wav"
    args = ["--teacher", "ana", "--robot", "r1", "--wav", str(wav), "--json", "--linger", "5"]
    result = subprocess.run(
        [VOXSHAPE, "teach", *bus_args(router, session_id, "teach"), *args, "--wait-speech", "60"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    assert '"kind": "understood"' in result.stdout and '"meaning": "good"' in result.stdout, (
        result.stdout
    )
    assert '"engine": "cascade"' in result.stdout, result.stdout


@needs_whisper
@pytest.mark.long
def test_the_speech_benchmark_measures_the_default_engine():
    argv = [sys.executable, "-m", "benchmarks.speech", "--engine", "default", "--language", "en"]
    root = FIXTURES.parents[2]
    result = subprocess.run(
        [*argv, "--json"], capture_output=True, text=True, timeout=300, cwd=root
    )
    assert result.returncode == 0, result.stderr
    (cascade, mock) = json.loads(result.stdout)["engines"]
    assert (cascade["engine"], mock["engine"]) == ("cascade", "mock")
    assert 0 < cascade["to_whisper_share"] < 1 and cascade["cpu_s"]["whisper"] > 0
    assert cascade["accuracy"] >= 0.9 and cascade["false_accept_rate"] <= 0.1
    assert 0 < cascade["latency_p50_s"] <= cascade["latency_p95_s"] < 2
    assert cascade["latency_n"] > 0

"""`voxshape speech` on a real bus: WAV files streamed by `voxshape teach` through a router
come out as utterances on the teacher's clock; the mock engine over the bus; garbage audio is
rejected and counted while the service goes on; a missing vosk model is a clear error."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import time
from dataclasses import replace

import msgpack
import pytest

from benchmarks.speech.scoring import load_clips
from tests.conftest import VOXSHAPE, bus_args, collect, quiet
from tests.test_speech import FIXTURES
from voxshape.cli import parser
from voxshape.protocol import AudioChunk, Utterance, teacher_key, to_wire
from voxshape.protocol.messages import SAMPLE_RATE
from voxshape.recognition.confusion import MockSettings
from voxshape.runtime import ConfigError, Node
from voxshape.runtime.audio import read_wav
from voxshape.runtime.settings import read_options
from voxshape.services.speech.node import SpeechOptions, engine_settings
from voxshape.services.speech.pocketsphinx_engine import PocketsphinxSettings

CLIPS = {c.path.name: c for c in load_clips(FIXTURES)}


def start_speech(spawn, router, session_id, cwd, *extra):
    return spawn(
        [VOXSHAPE, "speech", *bus_args(router, session_id, "speech"), *extra], cwd=cwd, text=True
    )


def teach(router, session_id, cwd, *extra, stdin="", timeout=60):
    """`voxshape teach` to a session of no robot (speech alone): it says its robot never
    appeared and exits 1, as to a robot that does not exist; what it showed."""
    result = subprocess.run(
        [VOXSHAPE, "teach", *bus_args(router, session_id, "teach"), "--json", *extra],
        input=stdin,
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=cwd,
    )
    shown = [json.loads(line) for line in result.stdout.splitlines()]
    assert result.returncode == 1, result.stderr
    assert "never appeared" in shown[-1]["message"], shown[-1]
    return shown


def speech_refuses(cwd, *args, env=None) -> str:
    """`voxshape speech ARGS` stops at once with exit code 2 and no traceback; its stderr."""
    result = subprocess.run(
        [VOXSHAPE, "speech", *args], capture_output=True, text=True, timeout=60, env=env, cwd=cwd
    )
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    return result.stderr


def stop(proc) -> str:
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    return err


def test_wav_files_streamed_by_teach_come_out_as_utterances_on_the_teachers_clock(
    spawn, router, session_id, client_config, tmp_path
):
    speech = start_speech(spawn, router, session_id, tmp_path)
    files = [
        "en-voc-turn-left-kal-diphone.wav",
        "en-oov-hello-en-us.wav",  # outside the vocabulary: nothing comes out
        "en-voc-very-good-cmu-us-slt-arctic-hts.wav",
    ]
    with Node("test", client_config("observer")) as node:
        node.input("utterance", teacher_key(session_id, "ana", "utterance"))
        args = ["--teacher", "ana", "--robot", "r7", "--fast", "--linger", "2"]
        args += ["--wait-speech", "30"]
        for name in files:
            args += ["--wav", str(FIXTURES / name)]
        shown = teach(router, session_id, tmp_path, *args)
        utterances = collect(node, 2, Utterance, timeout=10)
        assert quiet(node, 0.5) == []
    start = next(e for e in shown if e["event"] == "streaming")["start_time"]
    # where each file's speech lies on the teacher's clock (files are streamed back to back)
    offsets, clock = [], 0.0
    for name in files:
        offsets.append(clock)
        clock += len(read_wav(FIXTURES / name)) / SAMPLE_RATE + 0.5
    expected = [(files[0], offsets[0]), (files[2], offsets[2])]
    for utterance, (name, offset) in zip(utterances, expected, strict=True):
        clip = CLIPS[name]
        assert (utterance.teacher, utterance.robot, utterance.engine) == ("ana", "r7", "cascade")
        assert utterance.text == clip.text and utterance.language == "en"
        assert utterance.onset == pytest.approx(start + offset + clip.speech_start_s, abs=0.06)
        assert utterance.end == pytest.approx(start + offset + clip.speech_end_s, abs=0.1)
        assert 0 < utterance.confidence <= 1
    # no arbiter runs: what speech recognized is told as unanswered, what it rejected as such
    unanswered = [e["text"] for e in shown if e["event"] == "no_answer"]
    assert unanswered == ["turn left", "very good"]
    (rejected,) = [e for e in shown if e["event"] == "notice"]
    assert rejected["kind"] == "not_recognized" and "cascade heard speech" in rejected["message"]
    err = stop(speech)
    assert "received.audio=" in err and "speech.rejected=1" in err and "sent.utterance=2" in err


def test_the_mock_engine_hears_said_text_over_the_bus(
    spawn, router, session_id, client_config, tmp_path
):
    speech = start_speech(
        spawn, router, session_id, tmp_path, "--engine", "mock", "--latency", "0.3", "--seed", "1"
    )
    with Node("test", client_config("observer")) as node:
        node.input("utterance", teacher_key(session_id, "luz", "utterance"))
        teach(
            router,
            session_id,
            tmp_path,
            *("--teacher", "luz", "--language", "es", "--through-speech", "--linger", "1"),
            *("--wait-speech", "30"),
            stdin="muy bien\nizquierda\n# a comment\nbanana\n",
        )
        utterances = collect(node, 2, Utterance, timeout=10)
    assert [u.text for u in utterances] == ["muy bien", "izquierda"]
    for u in utterances:
        assert (u.engine, u.language, u.teacher) == ("mock", "es", "luz")
        assert u.recognized_at - u.end >= 0.3  # not before the mock's latency
    err = stop(speech)
    assert "mock.correct=2" in err and "mock.out_of_vocabulary=1" in err


@pytest.mark.parametrize(
    ("engine", "sent", "told"),
    [("pocketsphinx", "said", "hears audio, not text"), ("mock", "audio", "reads text, not audio")],
)
def test_input_the_engine_cannot_hear_is_told_to_its_sender_at_once(
    spawn, router, session_id, tmp_path, engine, sent, told
):
    speech = start_speech(spawn, router, session_id, tmp_path, "--engine", engine)
    if sent == "said":  # typed, through the speech service, as sim-teacher's text is sent
        args, stdin = ("--through-speech", "--wait-speech", "10"), "good\ngood\n"
    else:
        args, stdin = ("--wav", str(FIXTURES / "en-voc-good-en-us.wav"), "--wait-speech", "10"), ""
    started = time.monotonic()
    lines = teach(router, session_id, tmp_path, "--teacher", "ana", *args, stdin=stdin)
    notices = [line for line in lines if "not heard" in json.dumps(line)]
    assert len(notices) == 1 and told in json.dumps(notices[0]), lines  # once, not per word
    assert time.monotonic() - started < 30
    err = stop(speech)
    assert f"input this engine cannot hear teacher=ana sent={sent}" in err
    assert f"unheard.{sent}=" in err


def test_garbage_audio_is_rejected_and_counted_and_the_service_goes_on(
    spawn, router, session_id, client_config, tmp_path
):
    speech = start_speech(spawn, router, session_id, tmp_path)
    key = teacher_key(session_id, "eve", "audio")
    good = AudioChunk(
        teacher="eve",
        robot="r1",
        stream="s1",
        seq=0,
        sample_rate=16000,
        pcm=bytes(1600),
        capture_time=time.time(),
        final=False,
    )
    wire = to_wire(good)
    with Node("test", client_config("mallory")) as node:
        out = node.output("audio", key, keep=0)  # not kept: zenoh tells its subscribers
        deadline = time.monotonic() + 30
        while not out.has_subscribers() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert out.has_subscribers(), "the speech service never subscribed"
        node.zenoh.put(key, b"\x93not msgpack at all")
        node.zenoh.put(key, msgpack.packb({**wire, "sample_rate": 8000}, use_bin_type=True))
        node.zenoh.put(key, msgpack.packb({**wire, "pcm": bytes(1601)}, use_bin_type=True))
        node.zenoh.put(key, msgpack.packb({**wire, "pcm": bytes(40_000)}, use_bin_type=True))
        out.put(replace(good, teacher="mallory"))  # not eve's chunk
        out.put(good)
        out.put(replace(good, seq=0))  # repeated
        node.input("utterance", teacher_key(session_id, "ana", "utterance"))
        wav = str(FIXTURES / "en-voc-stop-en-us-klatt.wav")
        teach(router, session_id, tmp_path, "--teacher", "ana", "--wav", wav, "--fast")
        (utterance,) = collect(node, 1, Utterance, timeout=10)
    assert utterance.text == "stop"
    err = stop(speech)
    assert "rejected.audio=4" in err
    assert "audio.wrong_teacher=1" in err and "audio.out_of_order=1" in err
    assert "sample_rate" in err and "odd byte count" in err  # named in the logged reasons


def test_a_missing_vosk_model_is_a_clear_error_not_a_crash(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "VOSK_MODEL_PATH"}
    stderr = speech_refuses(tmp_path, "--engine", "vosk", "--language", "es", env=env)
    assert "https://alphacephei.com/vosk/models" in stderr
    assert "vosk-model-small-es-0.42" in stderr and "VOSK_MODEL_PATH" in stderr


@pytest.mark.parametrize(
    ("argv", "refused"),
    [
        (["--engine", "mock", "--model", "m"], "--model m: the mock engine hears text"),
        (["--engine", "vosk", "--dictionary", "d"], "--dictionary d: pocketsphinx's"),
        (["--engine", "cascade", "--error-rate", "0.2"], "--error-rate: the mock engine's"),
    ],
)
def test_a_setting_its_engine_cannot_honour_is_refused_at_start(argv, refused):
    args = parser(only="speech").parse_args(["speech", *argv])
    with pytest.raises(ConfigError, match=re.escape(refused)):
        engine_settings(args, read_options(SpeechOptions, args))


def test_the_engine_settings_it_runs_with_are_its_engines():
    args = parser(only="speech").parse_args(["speech", "--engine", "mock", "--error-rate", "0.2"])
    mock = engine_settings(args, read_options(SpeechOptions, args))
    assert isinstance(mock, MockSettings) and mock.error_rate == 0.2
    args = parser(only="speech").parse_args(["speech", "--engine", "cascade"])
    assert isinstance(
        engine_settings(args, read_options(SpeechOptions, args)), PocketsphinxSettings
    )

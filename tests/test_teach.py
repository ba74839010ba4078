"""`voxshape teach`: typed words reach the utterance topic, recordings are chunked on the
teacher's clock, the robot's status, what was understood and the robot's questions are shown,
and inputs that cannot work (no microphone, a WAV in the wrong format) are clear errors."""

from __future__ import annotations

import json
import subprocess
import time
import wave
from dataclasses import replace

import numpy as np
import pytest

from tests.conftest import VOXSHAPE, bus_args, collect, read_until, wait_present
from tests.test_web import Robot
from voxshape.protocol import (
    AudioChunk,
    Credit,
    CreditedFeedback,
    EpisodeEvent,
    HelpAnswer,
    HelpRequest,
    Said,
    TeacherNotice,
    Utterance,
    load_vocabulary,
    robot_key,
    teacher_key,
)
from voxshape.protocol.examples import example_messages
from voxshape.protocol.messages import SAMPLE_RATE
from voxshape.runtime import Node, Presence
from voxshape.services.speech.transcriber import not_recognized
from voxshape.services.teacher.screen import ask_hint
from voxshape.teaching.board import Board
from voxshape.teaching.sources import default_teacher_id, typed, typed_lines, wav_stream

VOCABULARY = load_vocabulary()


def test_typed_words_reach_the_utterance_topic(router, session_id, client_config, tmp_path):
    with Node("test", client_config("observer")) as node:
        node.input("utterance", teacher_key(session_id, "bob", "utterance"))
        result = subprocess.run(
            [
                VOXSHAPE,
                "teach",
                *bus_args(router, session_id, "teach"),
                *("--teacher", "bob", "--robot", "r2", "--linger", "0.5", "--json"),
            ],
            input="good\n\n  turn left  \nbanana\n",
            capture_output=True,
            text=True,
            timeout=60,
            cwd=tmp_path,
        )
        assert result.returncode == 1, result.stderr  # no robot r2 runs: taught nothing
        utterances = collect(node, 3, Utterance, timeout=10)
    assert [u.text for u in utterances] == ["good", "turn left", "banana"]
    for u in utterances:
        assert (u.teacher, u.robot, u.engine, u.confidence, u.language) == (
            "bob",
            "r2",
            "typed",
            1.0,
            "en",
        )
        assert u.onset == u.end == u.recognized_at
    shown = [json.loads(line) for line in result.stdout.splitlines()]
    # no arbiter runs: each word is told once that nobody answered, never "understood"
    unanswered = [e["text"] for e in shown if e["event"] == "no_answer"]
    assert unanswered == ["good", "turn left", "banana"]
    assert not [e for e in shown if e["event"] == "notice"]


def test_no_microphone_is_a_clear_error(tmp_path):
    result = subprocess.run(
        [VOXSHAPE, "teach", "--mic"], capture_output=True, text=True, timeout=60, cwd=tmp_path
    )
    if result.returncode == 0:
        pytest.skip("this machine has a microphone")
    assert result.returncode == 2
    assert "no audio library" in result.stderr or "no usable microphone" in result.stderr
    assert "--wav" in result.stderr and "Traceback" not in result.stderr


def test_a_wav_in_another_format_says_how_to_convert_it(tmp_path):
    path = tmp_path / "cd.wav"
    with wave.open(str(path), "wb") as w:
        w.setnchannels(2)
        w.setsampwidth(2)
        w.setframerate(44100)
        w.writeframes(bytes(4 * 441))
    for wav, expected in ((path, "44100 Hz, 2 channel(s)"), (tmp_path / "no.wav", "no such")):
        result = subprocess.run(
            [VOXSHAPE, "teach", "--wav", str(wav)],
            capture_output=True,
            text=True,
            timeout=60,
            cwd=tmp_path,
        )
        assert result.returncode == 2 and expected in result.stderr, result.stderr
    assert "sox" in result.stderr or "no such" in result.stderr


def test_recordings_are_chunked_back_to_back_on_the_teachers_clock():
    one, two = np.ones(8000, np.int16), np.ones(700, np.int16)
    paced = wav_stream([one, two], "ana", "r1", start_time=1000.0)
    chunks = [s.message for s in paced]
    assert all(isinstance(c, AudioChunk) for c in chunks)
    first = [c for c in chunks if c.stream == chunks[0].stream]
    second = [c for c in chunks if c.stream != chunks[0].stream]
    assert [c.seq for c in first] == list(range(10)) and first[-1].final
    assert len(second) == 1 and second[0].final and len(second[0].pcm) == 2 * 700
    assert [c.capture_time for c in first[:3]] == pytest.approx([1000.0, 1000.05, 1000.1])
    assert second[0].capture_time == pytest.approx(1000.0 + 0.5 + 0.5)  # after a 0.5 s pause
    assert paced[0].due_s == pytest.approx(0.05)  # sent once "recorded"
    assert paced[-1].due_s == pytest.approx(1.0 + 700 / SAMPLE_RATE)
    assert all(s.due_s == 0 for s in wav_stream([one], "ana", "r1", 0.0, fast=True))


def test_typed_lines_and_what_they_become():
    assert list(typed_lines(iter(["good\n", "\n", "# note\n", "  turn left \n"]))) == [
        "good",
        "turn left",
    ]
    said = typed("muy bien", "ana", "r1", "es", 5.0, through_speech=True)
    assert isinstance(said, Said) and (said.onset, said.end, said.language) == (5.0, 5.0, "es")
    utterance = typed("good", "ana", "r1", "en", 5.0, through_speech=False)
    assert isinstance(utterance, Utterance) and utterance.engine == "typed"
    assert default_teacher_id()  # a usable id whatever the login name


def test_the_board_shows_status_episodes_feedback_and_what_was_understood():
    examples = {m.TYPE: m for _, m in example_messages("s1")}
    board = Board(status_every_s=2.0)
    obs = examples["observation"]
    (status,) = board.observation(obs, now=10.0)
    assert "episode 3, step 57" in status.text and "last reward -1" in status.text
    assert board.observation(obs, now=11.0) == []  # not more often than asked
    episode = examples["episode"]
    assert isinstance(episode, EpisodeEvent)
    assert "ended: goal after 105 steps" in board.episode(episode)[0].text
    feedback = CreditedFeedback(
        robot="r1",
        kind="command",
        reward=None,
        command="left",
        credits=(Credit(step=7, weight=1.0),),
        sources=(examples["utterance"].id,),
        teachers=("ana",),
    )
    assert "took left from ana" in board.feedback(feedback)[0].text


def notice(u: Utterance, kind: str, text: str) -> TeacherNotice:
    return TeacherNotice(
        teacher=u.teacher, robot=u.robot, utterance=u.id, kind=kind, meaning=None, text=text
    )


def test_each_utterance_gets_one_line_once_the_arbiter_answers():
    examples = {m.TYPE: m for _, m in example_messages("s1")}
    heard = examples["utterance"]  # "muy bien", mock, confidence 0.87
    board = Board(answer_within_s=1.0)
    assert board.recognized(heard, now=10.0) == [] and board.waiting
    assert board.tick(10.5) == []
    (line,) = board.notice(notice(heard, "low_confidence", "not used: heard it"), now=10.6)
    assert line.text == "not used: heard it (mock, confidence 0.87)"
    assert (line.event, line.data["kind"], line.data["text"]) == (
        "notice",
        "low_confidence",
        "muy bien",
    )
    assert not board.waiting and board.tick(20.0) == []  # answered: nothing more


def test_a_verdict_that_overtakes_its_utterance_waits_for_it():
    """The arbiter's notice and the speech service's utterance travel on two keys (zenoh
    orders per key only): a notice may come first. It is shown with what was heard once the
    utterance comes, or as it is after `answer_within_s` if the utterance never does."""
    examples = {m.TYPE: m for _, m in example_messages("s1")}
    heard = examples["utterance"]  # "muy bien", mock, confidence 0.87
    board = Board(answer_within_s=1.0)
    assert board.notice(notice(heard, "understood", "understood 'muy bien'"), now=10.0) == []
    (line,) = board.recognized(heard, now=10.2)
    assert line.text == "understood 'muy bien' (mock, confidence 0.87)"
    assert (line.data["kind"], line.data["text"], line.data["late"]) == (
        "understood",
        "muy bien",
        False,
    )
    assert not board.waiting and board.tick(20.0) == []
    lost = replace(heard, id="u-never-came")
    assert board.notice(notice(lost, "understood", "understood 'muy bien'"), now=30.0) == []
    assert board.tick(30.9) == []
    (alone,) = board.tick(31.0)
    assert alone.text == "understood 'muy bien'" and "text" not in alone.data


def test_an_unanswered_utterance_is_told_once_and_a_late_answer_shown_as_late():
    said = typed("good", "ana", "r1", "en", 100.0, False)
    board = Board(answer_within_s=1.0, no_answer_hint="no arbiter heard it")
    board.sent(said, now=5.0)
    board.recognized(said, now=5.01)  # the echo of its own typed words: still one
    assert board.tick(5.9) == []
    (line,) = board.tick(6.0)
    assert line.text == "no answer to 'good' within 1 s: no arbiter heard it"
    assert line.event == "no_answer" and board.tick(9.0) == []
    (late,) = board.notice(notice(said, "understood", "understood 'good': good (+10)"), 9.5)
    assert late.text == "late answer: understood 'good': good (+10) (typed)" and late.data["late"]


def test_silence_after_a_rate_limit_is_explained_as_the_rate_limit():
    board = Board(answer_within_s=1.0)
    first, second = (typed(w, "ana", "r1", "en", 0.0, False) for w in ("good", "bad"))
    board.sent(first, 0.0)
    board.sent(second, 0.0)
    board.notice(notice(first, "rate_limited", "not used: too many words"), 0.1)
    (line,) = board.tick(1.0)
    assert "rate limited" in line.text


def test_speech_the_speech_service_rejected_gets_its_line():
    rejected = not_recognized("ana", "r1", "pocketsphinx")
    (line,) = Board().notice(rejected, now=1.0)
    assert line.text.startswith("not recognized: pocketsphinx heard speech")


def test_a_robot_nothing_is_seen_of_is_told_once():
    examples = {m.TYPE: m for _, m in example_messages("s1")}
    board = Board(answer_within_s=1.0, robot_missing="robot 'r1' is not running", started_at=0.0)
    assert board.tick(0.5) == []
    assert [s.text for s in board.tick(1.0)] == ["robot 'r1' is not running"]
    assert board.tick(2.0) == []
    back, status = board.observation(examples["observation"], now=3.0)
    assert back.text == "robot r1 is running now" and status.event == "status"


def test_the_teacher_syncs_its_clock_and_shows_what_the_arbiter_made_of_its_words(
    spawn, router, session_id, client_config, tmp_path
):
    arbiter = spawn(
        [VOXSHAPE, "arbiter", *bus_args(router, session_id, "arbiter")], cwd=tmp_path, text=True
    )
    with Node("test", client_config("observer")) as node:  # wait until the arbiter is up
        node.watch_presence(node="arbiter")
        deadline = time.monotonic() + 20
        while not isinstance(node.poll(0.1), Presence) and time.monotonic() < deadline:
            pass
    time.sleep(0.3)  # its subscriptions reach the router with its token
    result = subprocess.run(
        [
            VOXSHAPE,
            "teach",
            *bus_args(router, session_id, "teach"),
            *("--teacher", "bob", "--robot", "r9", "--linger", "2.5", "--json"),
        ],
        input="good\n",
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )
    assert result.returncode == 1, result.stderr  # there is no robot r9
    shown = [json.loads(line) for line in result.stdout.splitlines()]
    assert shown[-1]["message"] == "robot 'r9' never appeared; nothing it was told was taught"
    (clock,) = [e for e in shown if e["event"] == "clock"]
    # one host, one clock: the offset within what the round trip allows
    assert abs(clock["offset"]) <= clock["rtt"] / 2 + 0.005, clock
    (notice,) = [e for e in shown if e["event"] == "notice"]
    assert (notice["robot"], notice["kind"]) == ("r9", "unknown_robot"), notice
    arbiter.terminate()
    assert arbiter.wait(20) == 0


def test_a_question_gets_its_line_with_a_hint_in_the_teachers_words_and_the_answer_who_gave_it():
    question = HelpRequest(
        robot="r1", episode=3, step=405, reason="stuck", detail="stuck for 10 s", x=1.2, y=-0.4
    )
    board = Board(ask_hint=ask_hint(VOCABULARY, "en"))
    (line,) = board.question(question)
    assert line.text == "r1 asks: which way? stuck for 10 s — say left, right or forward"
    assert (line.event, line.data["question"], line.data["step"]) == ("question", question.id, 405)
    assert ask_hint(VOCABULARY, "es") == "say izquierda, derecha or avanzar"
    answer = HelpAnswer(
        robot="r1",
        question=question.id,
        step=405,
        teacher="ana",
        meaning="left",
        utterance="0" * 32,
    )
    (line,) = board.answer(answer)
    assert line.text == "answered by ana: left" and line.data["teacher"] == "ana"
    # what the bus says is printed without its control characters (escape sequences)
    (odd,) = Board().question(replace(question, detail="\x1b[31mred"))
    assert odd.text == "r1 asks: which way? ?[31mred"


def test_the_teacher_hears_the_robots_question_with_the_bell_and_who_answered(
    spawn, router, session_id, client_config, tmp_path
):
    """A real arbiter and `voxshape teach`; the test is the robot: it publishes observations
    and asks. Bob sees the question, types "left", and sees that he answered it; the robot
    gets the command credited to the question's step."""
    spawn([VOXSHAPE, "arbiter", *bus_args(router, session_id, "arbiter")], cwd=tmp_path)
    with Node("test", client_config("robot")) as node:
        node.watch_presence()
        node.input("feedback", robot_key(session_id, "r1", "feedback"))
        help_ = node.output("help", robot_key(session_id, "r1", "help"))
        wait_present(node, "arbiter")
        robot = Robot(node, session_id, hz=10.0)
        robot.start()
        teach = spawn(
            [
                *(VOXSHAPE, "teach", *bus_args(router, session_id, "teach")),
                *("--teacher", "bob", "--robot", "r1", "--linger", "1"),
            ],
            stdin=subprocess.PIPE,
            text=True,
            cwd=tmp_path,
        )
        try:
            wait_present(node, "teach")
            question = HelpRequest(
                robot="r1", episode=0, step=7, reason="stuck", detail="stuck for 10 s", x=1, y=1
            )
            help_.put(question)
            asked = read_until(teach, "asks: which way", timeout=10)[-1]
            assert asked == "\a" + "r1 asks: which way? stuck for 10 s — say left, right or forward"
            teach.stdin.write("left\n")
            teach.stdin.flush()
            (feedback,) = collect(node, 1, CreditedFeedback, timeout=10)
            answered = read_until(teach, "answered by", timeout=10)[-1]
        finally:
            robot.stopping.set()
            robot.join(5)
        teach.stdin.close()
        assert teach.wait(20) == 0
    assert answered == "answered by bob: left"
    assert (feedback.kind, feedback.command, feedback.teachers) == ("command", "left", ("bob",))
    assert [(c.step, c.weight) for c in feedback.credits] == [(7, 1.0)]

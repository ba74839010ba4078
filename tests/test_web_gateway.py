"""The web gateway's pure core (bus messages <-> browser JSON), without a bus: thinned
observations, questions and answers, logins, typed words and pressed audio on the gateway's
clock, the clock offset, malformed frames, the welcome."""

from __future__ import annotations

import json

import pytest

from voxshape.protocol import (
    AudioChunk,
    EpisodeEvent,
    HelpAnswer,
    HelpRequest,
    TeacherNotice,
    TeachingStats,
    Utterance,
    load_vocabulary,
)
from voxshape.services.arbiter.scripted import scripted_observation
from voxshape.services.web.frames import BrowserError, parse_frame, parse_login
from voxshape.services.web.gateway import AUDIO_HEADER, Teaching
from voxshape.services.web.page_json import SessionView, map_json, vocabulary_json
from voxshape.services.web.robots import QUESTION_OPEN_S, Robots
from voxshape.teaching.board import Board
from voxshape.world.maps import load_map


def test_observations_are_thinned_to_ten_a_second_per_robot_the_latest_winning():
    robots = Robots(hz=10)
    sent: list[dict] = []
    for i in range(200):  # two robots at 100 Hz for two seconds
        now = 1000.0 + i * 0.01
        for robot in ("r1", "r2"):
            sent += robots.observation(scripted_observation(robot, i, now), now)
        sent += robots.due(now)
    for robot in ("r1", "r2"):
        mine = [m for m in sent if m["robot"] == robot]
        stamps = [m["stamp"] for m in mine]
        # 10 a second after the first 2 at once: never 3 within 100 ms
        assert len(mine) <= 22 and all(
            c - a >= 99.9 for a, _, c in zip(stamps, stamps[1:], stamps[2:], strict=False)
        )
        # each forwarded one is the newest fed when it went (the other robot's may be one
        # step behind: its newest had not come yet)
        assert all(0 <= round((m["stamp"] / 1000 - 1000.0) / 0.01) - m["step"] <= 1 for m in mine)
    assert robots.seen == ["r1", "r2"]
    assert robots.due(1010.0)[0]["step"] == 199  # the last one waits for its slot


def test_the_curve_gets_an_episode_once_its_interventions_are_final():
    robots = Robots()
    ended = EpisodeEvent(
        robot="r1",
        episode=3,
        step=90,
        kind="goal",
        episode_steps=40,
        sim_time=9.0,
        wall_time=1.0,
        env_return=55.0,
    )
    assert robots.episode(ended)[0] == {
        "type": "episode",
        "robot": "r1",
        "episode": 3,
        "kind": "goal",
        "steps": 40,
        "return": 55.0,
    }
    stats = TeachingStats(robot="r1", episode=3, final=False, interventions=2, teachers=())
    assert robots.teaching(stats) == []
    (point,) = robots.teaching(TeachingStats(**{**stats.__dict__, "final": True}))
    assert (point["episode"], point["return"], point["steps"], point["interventions"]) == (
        3,
        55.0,
        40,
        2,
    )
    assert list(robots.curve) == [point]


def ask(robot: str = "r1", step: int = 405, detail: str = "stuck for 10 s") -> HelpRequest:
    return HelpRequest(
        robot=robot, episode=3, step=step, reason="stuck", detail=detail, x=1.23456, y=0.5
    )


def answered(question: HelpRequest, teacher: str = "ana") -> HelpAnswer:
    return HelpAnswer(
        robot=question.robot,
        question=question.id,
        step=question.step,
        teacher=teacher,
        meaning="left",
        utterance="0" * 32,
    )


def test_a_question_and_its_answer_go_to_every_page_bounded_and_open_ones_to_late_pages():
    robots = Robots()
    question = ask()
    (item,) = robots.question(question, 100.0, key_robot="r1")
    assert item == {
        "type": "question",
        "robot": "r1",
        "question": question.id,
        "episode": 3,
        "step": 405,
        "reason": "stuck",
        "detail": "stuck for 10 s",
        "x": 1.2346,
        "y": 0.5,
        "text": "r1 asks: which way? stuck for 10 s",
        "stamp": 100_000.0,
    }
    # a page that joins meanwhile is shown it; once answered, or QUESTION_OPEN_S on, not
    view = SessionView("s1", False, "en", {}, None, None)
    assert robots.welcome(view, "ben", 104.0)["questions"] == [item]
    assert robots.open_questions(100.0 + QUESTION_OPEN_S) == []
    (answer,) = robots.answer(answered(question), 101.0)
    assert answer["text"] == "answered by ana: left" and answer["question"] == question.id
    assert (answer["type"], answer["teacher"], answer["step"]) == ("answer", "ana", 405)
    assert robots.open_questions(101.5) == []
    # rare, and bounded anyway: one a robot a second; none on another robot's key
    assert robots.question(ask(step=406), 100.5) == []
    assert robots.question(ask("r2"), 101.0, key_robot="r1") == []
    assert robots.question(ask("r2"), 101.0, key_robot="r2") != []
    flood = [m for k in range(100) for m in robots.question(ask(f"x{k}"), 102.0)]
    assert len(flood) <= 10  # every robot's together: a burst of 10, then 5 a second
    assert len(robots.open_questions(102.0)) <= 64
    # bus text is text: control characters never reach a terminal (the page uses textContent)
    (odd,) = robots.question(ask("r3", detail="\x1b[2Jgone\a"), 200.0)
    assert odd["text"] == "r3 asks: which way? ?[2Jgone?"


def test_a_login_names_its_teacher_and_a_secured_one_needs_its_password():
    assert parse_login({"type": "login", "teacher": "ana"}, secured=False).teacher == "ana"
    secured = parse_login({"type": "login", "teacher": "ben", "user": "ana", "password": "x"}, True)
    assert (secured.teacher, secured.user, secured.password) == ("ana", "ana", "x")
    with pytest.raises(BrowserError, match="secured: log in with your user name and password"):
        parse_login({"type": "login", "teacher": "ana"}, secured=True)
    with pytest.raises(BrowserError, match="not a usable teacher id"):
        parse_login({"type": "login", "teacher": "a/b"}, secured=False)
    with pytest.raises(BrowserError, match="log in first"):
        parse_login({"type": "say", "text": "good"}, secured=False)


def teaching(seen: tuple[str, ...] = ("r1",)) -> Teaching:
    robots = Robots()
    for robot in seen:
        robots.observation(scripted_observation(robot, 0, 1.0), 1.0)
    return Teaching("ana", robots, Board(answer_within_s=1.0, no_answer_hint="nobody heard"))


def test_typed_words_become_utterances_on_the_gateways_clock_and_get_the_terminals_line():
    t = teaching()
    now = 2000.0
    reply = t.text({"type": "clock", "t0": 1_994_999.0}, now, 0.0).replies[0]
    assert reply["offset_ms"] == pytest.approx(5001.0) and reply["rtt_ms"] is None
    # a browser that measured its round trips reports its best: it wins over the one-way bound
    reply = t.text(
        {"type": "clock", "t0": 1_995_000.0, "offset_ms": 5000.0, "rtt_ms": 2.0}, now, 0.0
    ).replies[0]
    assert (reply["offset_ms"], reply["rtt_ms"]) == (5000.0, 2.0)
    (u,) = t.text({"type": "say", "text": " good ", "onset": 1_994_900.0}, now, 10.0).messages
    assert isinstance(u, Utterance)
    assert (u.teacher, u.robot, u.text, u.engine, u.confidence) == ("ana", "r1", "good", "typed", 1)
    assert u.onset == pytest.approx(1999.9) and u.recognized_at == now
    # the verdict is the line `voxshape teach` shows; an unanswered one is told so after 1 s
    notice = TeacherNotice(
        teacher="ana",
        robot="r1",
        utterance=u.id,
        kind="understood",
        meaning="good",
        text="understood 'good': reward +10",
    )
    expected = Board(answer_within_s=1.0)
    expected.sent(u, 10.0)
    (line,) = t.notice(notice, 10.5)
    assert (
        line["text"]
        == expected.notice(notice, 10.5)[0].text
        == ("understood 'good': reward +10 (typed)")
    )
    assert (line["kind"], line["heard"], line["late"], line["utterance"]) == (
        "understood",
        "good",
        False,
        u.id,
    )
    (other,) = t.text({"type": "say", "text": "left"}, now, 20.0).messages
    assert t.tick(20.9) == []
    (late,) = t.tick(21.0)
    assert late["kind"] == "no_answer" and late["utterance"] == other.id
    assert late["text"] == "no answer to 'left' within 1 s: nobody heard"


def frame(browser_ms: float, samples: int) -> bytes:
    return AUDIO_HEADER.pack(browser_ms) + bytes(2 * samples)


def test_a_press_is_one_stream_its_chunks_on_the_gateways_clock_and_final_at_release():
    t = teaching()
    t.text({"type": "clock", "t0": 995_000.0, "offset_ms": 5000.0, "rtt_ms": 1.0}, 1000.0, 0)
    with pytest.raises(BrowserError, match="audio outside a press"):
        t.audio(frame(995_000.0, 800), 1000.0)
    assert t.text({"type": "talk", "state": "start"}, 1000.0, 0).messages == []
    chunks = [
        *t.audio(frame(995_100.0, 800), 1000.2).messages,
        *t.audio(frame(995_150.0, 800), 1000.25).messages,
    ]
    (last,) = t.text({"type": "talk", "state": "stop"}, 1000.3, 0).messages
    chunks.append(last)
    assert all(isinstance(c, AudioChunk) for c in chunks)
    assert [c.seq for c in chunks] == [0, 1, 2] and len({c.stream for c in chunks}) == 1
    assert [c.final for c in chunks] == [False, False, True] and last.pcm == b""
    assert [c.capture_time for c in chunks] == pytest.approx([1000.1, 1000.15, 1000.2])
    # the next press is another stream; over 1 s of audio is cut into chunks of 1 s
    t.text({"type": "talk", "state": "start", "robot": "r2"}, 1001.0, 0)
    long = t.audio(frame(996_000.0, 24_000), 1002.0).messages
    assert [len(c.pcm) for c in long] == [32_000, 16_000]
    assert long[0].stream != chunks[0].stream and long[0].robot == "r2"
    assert [c.capture_time for c in long] == pytest.approx([1001.0, 1002.0])
    for bad in (b"\x00" * 5, frame(996_000.0, 10) + b"\x00"):
        with pytest.raises(BrowserError, match="8 bytes of capture time"):
            t.audio(bad, 1002.0)


def test_what_cannot_be_used_is_an_error_not_a_message():
    t = teaching(seen=())
    for data, error in (
        ({"type": "say", "text": "good"}, "no robot is running yet"),
        ({"type": "say", "text": ""}, "non-empty string"),
        ({"type": "say", "text": "good", "robot": "r1", "language": "fr"}, "language"),
        ({"type": "clock", "t0": "soon"}, "t0 must be a finite number"),
        ({"type": "talk", "state": "maybe"}, "start or stop"),
        ({"type": "placed"}, "placed: no robot is running yet"),
        ({"type": "placed", "robot": "r 1"}, "placed: 'r 1' contains ' '"),
        ({"type": "fly"}, "unknown message type 'fly'"),
        ({"type": "login", "teacher": "ben"}, "already logged in"),
    ):
        with pytest.raises(BrowserError, match=error):
            t.text(data, 1000.0, 0.0)


def test_a_reported_clock_offset_is_bounded_by_what_the_round_trip_allows():
    t = teaching()
    # one way: t1 - t0 = 5000 ms; a browser claiming its clock is 9 s off is not believed
    reply = t.text(
        {"type": "clock", "t0": 1_995_000.0, "offset_ms": -4000.0, "rtt_ms": 60_000.0},
        2000.0,
        0.0,
    ).replies[0]
    assert reply["offset_ms"] == pytest.approx(5000.0 - 1000.0)
    reply = t.text(
        {"type": "clock", "t0": 1_995_000.0, "offset_ms": 9000.0, "rtt_ms": 2.0}, 2000.0, 0.0
    ).replies[0]
    assert reply["offset_ms"] == pytest.approx(5000.0)


def test_a_teachers_audio_is_held_to_about_real_time():
    t = teaching()
    t.text({"type": "talk", "state": "start"}, 1000.0, 0)
    sent = 0
    for k in range(100):  # 0.5 s of audio every 10 ms: 50x real time
        try:
            t.audio(frame(1_000_000.0, 8000), 1000.0 + k * 0.01)
            sent += 1
        except BrowserError as e:
            assert "faster than real time" in str(e)
    assert 6 <= sent <= 9  # the 3 s burst and the 1 s that came meanwhile, in 0.5 s frames


def test_malformed_frames_are_errors_not_exceptions():
    t = teaching()
    for text, error in (
        ('{"type": "clock", "t0": ' + "9" * 401 + "}", "t0 must be a finite number"),
        ('{"type": "say", "text": "good", "onset": -' + "9" * 401 + "}", "finite number"),
        ("[" * 100_000 + "]" * 100_000, "over 4096 bytes"),
        ("[" * 2000 + "]" * 2000, "not JSON"),
        ("[1]", "a JSON object"),
    ):
        with pytest.raises(BrowserError, match=error):
            t.text(parse_frame(text), 1000.0, 0.0)
    with pytest.raises(BrowserError, match="over 4096 bytes"):
        parse_frame('{"type": "login", "password": "' + "x" * 300_000 + '"}')


def test_the_welcome_draws_the_map_and_lists_the_vocabulary():
    m = map_json(load_map("2"))
    assert len(m["walls"]) >= 4 and m["goal"]["radius"] > 0
    assert set(m["start"]) == {"x", "y", "theta", "jitter"}
    json.dumps(m)
    words = vocabulary_json(load_vocabulary())
    good = next(w for w in words["en"] if w["phrase"] == "good")
    assert (good["meaning"], good["kind"], good["reward"]) == ("good", "qualifier", 10.0)
    assert any(w["kind"] == "command" for w in words["es"])

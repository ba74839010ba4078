"""`voxshape web`: the pure gateway (bus messages <-> browser JSON), and a real `voxshape web`
process on a real bus, driven by a WebSocket client as a browser would: login, typed words,
push-to-talk audio, throttled observations, origins, limits, and a secured router."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import ssl
import subprocess
import threading
import time
from collections.abc import Callable
from typing import Any

import aiohttp
import pytest

from tests.conftest import (
    VOXSHAPE,
    bus_args,
    collect,
    free_port,
    read_until,
    wait_for_port,
    wait_present,
    web_log_path,
)
from voxshape.protocol import (
    AudioChunk,
    EpisodeEvent,
    HelpAnswer,
    HelpRequest,
    Placed,
    TeacherNotice,
    TeachingStats,
    Utterance,
    load_vocabulary,
    robot_key,
    teacher_key,
)
from voxshape.runtime import Node, bus_config
from voxshape.services.arbiter.scripted import observation
from voxshape.services.web.frames import BrowserError, parse_frame, parse_login
from voxshape.services.web.gateway import AUDIO_HEADER, Teaching
from voxshape.services.web.page_json import SessionView, map_json, vocabulary_json
from voxshape.services.web.robots import QUESTION_OPEN_S, Robots
from voxshape.services.web.server import REFUSED
from voxshape.teaching.board import Board
from voxshape.world.maps import load_map

# -- the pure core -----------------------------------------------------------------------------


def test_observations_are_thinned_to_ten_a_second_per_robot_the_latest_winning():
    robots = Robots(hz=10)
    sent: list[dict] = []
    for i in range(200):  # two robots at 100 Hz for two seconds
        now = 1000.0 + i * 0.01
        for robot in ("r1", "r2"):
            sent += robots.observation(observation(robot, i, now), now)
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
        robots.observation(observation(robot, 0, 1.0), 1.0)
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


# -- a real `voxshape web` on a real bus ------------------------------------------------------


def start_web(spawn: Callable, argv: list[str], env: dict[str, str] | None = None) -> int:
    """`voxshape web` on a free port; returns the port once it listens."""
    port = free_port()
    log = web_log_path(port)
    with log.open("w") as out:  # a file: a full pipe would block it
        spawn(
            [VOXSHAPE, "web", *argv, "--port", str(port)],
            stdout=out,
            stderr=subprocess.STDOUT,
            env={**os.environ, **(env or {})},
        )
    wait_for_port(port, timeout=30.0)
    return port


async def open_page(
    http: aiohttp.ClientSession, port: int, login: dict[str, Any]
) -> tuple[aiohttp.ClientWebSocketResponse, dict]:
    origin = f"http://127.0.0.1:{port}"
    ws = await http.ws_connect(f"{origin}/ws", origin=origin)
    await ws.send_json({"type": "login", "user": None, "password": None, **login})
    return ws, await ws.receive_json(timeout=15)


async def until(
    ws: aiohttp.ClientWebSocketResponse, match: Callable[[dict], bool], timeout: float = 15.0
) -> tuple[dict, list[dict]]:
    """The first message that matches, and every one before it."""
    seen: list[dict] = []
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        msg = await ws.receive(timeout=left)
        assert msg.type == aiohttp.WSMsgType.TEXT, msg
        data = json.loads(msg.data)
        if match(data):
            return data, seen
        seen.append(data)
    raise AssertionError(f"nothing matched within {timeout} s; got {[m['type'] for m in seen]}")


class Robot(threading.Thread):
    """Observations of r1 at `hz`, as a simulator would publish them, until stopped."""

    def __init__(self, node: Node, session: str, hz: float = 50.0) -> None:
        super().__init__(daemon=True)
        self.out = node.output("obs", robot_key(session, "r1", "obs"))
        self.period, self.stopping = 1.0 / hz, threading.Event()

    def run(self) -> None:
        start = time.time()
        for k in range(100_000):
            if self.stopping.wait(max(0.0, start + k * self.period - time.time())):
                return
            self.out.put(observation("r1", k, time.time()))


def test_a_browser_teaches_through_the_page(spawn, router, session_id, client_config):
    """Typed words reach the arbiter as this teacher's and their verdict comes back as the
    terminal's line; a press's audio becomes chunks on the gateway's clock; observations are
    thinned to 10 a second; another origin, oversize and too-fast frames are refused and the
    server goes on."""
    spawn([VOXSHAPE, "arbiter", *bus_args(router, session_id, "arbiter")])
    port = start_web(spawn, [*bus_args(router, session_id, "web"), "--task", "2"])
    with Node("test", client_config("watcher")) as node:
        node.watch_presence()
        node.input("utterance", teacher_key(session_id, "ana", "utterance"))
        node.input("audio", teacher_key(session_id, "ana", "audio"))
        node.input("placed", teacher_key(session_id, "ana", "placed"))
        wait_present(node, {"arbiter", "web"})
        robot = Robot(node, session_id)
        robot.start()
        try:
            asyncio.run(browse(port, node))
        finally:
            robot.stopping.set()
            robot.join(5)


async def browse(port: int, node: Node) -> None:
    async with aiohttp.ClientSession() as http:
        ws, welcome = await open_page(http, port, {"teacher": "ana"})
        assert welcome["type"] == "welcome" and welcome["teacher"] == "ana"
        assert not welcome["secured"] and welcome["map"]["name"].startswith("Task 2")
        assert welcome["viewer"] is None and "good" in {
            w["phrase"] for w in welcome["vocabulary"]["en"]
        }

        # Observations: at most 10 a second (2 at once), the newest of each slot.
        await until(ws, lambda m: m["type"] == "obs")
        t0 = time.monotonic()
        _, seen = await until(ws, lambda m: time.monotonic() - t0 > 2.0, timeout=10)
        stamps = [m["stamp"] for m in seen if m["type"] == "obs"]
        assert 12 <= len(stamps) <= 22, len(stamps)
        assert all(c - a >= 99.0 for a, _, c in zip(stamps, stamps[1:], stamps[2:], strict=False))

        # A typed word: the arbiter's verdict, as `voxshape teach` shows it.
        await ws.send_json({"type": "say", "robot": "r1", "text": "good"})
        notice, _ = await until(ws, lambda m: m["type"] == "notice")
        assert notice["kind"] == "understood" and notice["heard"] == "good", notice
        assert notice["text"].endswith("(typed)")
        (u,) = await asyncio.to_thread(collect, node, 1, Utterance)
        assert (u.teacher, u.robot, u.text, u.id) == ("ana", "r1", "good", notice["utterance"])

        # The button of a real robot waiting between episodes: it is placed, as ana says.
        await ws.send_json({"type": "placed", "robot": "r1"})
        (placed,) = await asyncio.to_thread(collect, node, 1, Placed)
        assert (placed.teacher, placed.robot) == ("ana", "r1")

        # Push-to-talk with a browser clock 5 s behind the gateway's.
        skew = 5000.0
        await ws.send_json({"type": "clock", "t0": time.time() * 1000 - skew})
        reply, _ = await until(ws, lambda m: m["type"] == "clock")
        assert skew <= reply["offset_ms"] < skew + 50, reply
        await ws.send_json({"type": "clock", "t0": 0.0, "offset_ms": skew, "rtt_ms": 0.5})
        await until(ws, lambda m: m["type"] == "clock")
        await ws.send_json({"type": "talk", "robot": "r1", "state": "start"})
        first = time.time() * 1000 - skew - 100
        await ws.send_bytes(AUDIO_HEADER.pack(first) + bytes(1600))
        await ws.send_bytes(AUDIO_HEADER.pack(first + 50) + bytes(1600))
        await ws.send_json({"type": "talk", "robot": "r1", "state": "stop"})
        chunks = await asyncio.to_thread(collect, node, 3, AudioChunk)
        assert [c.seq for c in chunks] == [0, 1, 2] and [c.final for c in chunks][-1]
        assert len({c.stream for c in chunks}) == 1 and chunks[0].teacher == "ana"
        assert [c.capture_time for c in chunks] == pytest.approx(
            [(first + skew) / 1000, (first + 50 + skew) / 1000, (first + 100 + skew) / 1000]
        )

        # Limits: an error each, and the page goes on.
        await ws.send_str(json.dumps({"type": "say", "text": "x" * 5000}))
        error, _ = await until(ws, lambda m: m["type"] == "error")
        assert "over 4096 bytes" in error["text"]
        await ws.send_bytes(AUDIO_HEADER.pack(0.0) + bytes(70_000))
        error, _ = await until(ws, lambda m: m["type"] == "error")
        assert "over 65536 bytes" in error["text"]
        for _ in range(120):
            await ws.send_json({"type": "watch", "robot": "r1"})
        error, _ = await until(ws, lambda m: m["type"] == "error")
        assert "too many messages" in error["text"]
        await asyncio.sleep(1.1)
        await ws.send_json({"type": "clock", "t0": time.time() * 1000})
        await until(ws, lambda m: m["type"] == "clock")
        await ws.close()

        # Another site's page cannot open the socket.
        with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
            await http.ws_connect(f"http://127.0.0.1:{port}/ws", origin="http://evil.example")
        assert refused.value.status == 403
        async with http.get(f"http://127.0.0.1:{port}/") as page:
            assert page.status == 200 and "<html" in (await page.text()).lower()


# -- a secured session --------------------------------------------------------------------------


def test_on_a_secured_router_a_browser_logs_in_as_its_user_and_speaks_only_as_itself(
    spawn, secured
):
    endpoint, secrets = secured
    env = {"VOXSHAPE_SESSION": "secured", "VOXSHAPE_SECRETS": str(secrets)}
    env["VOXSHAPE_ACCESS"] = str(secrets / "access.toml")  # the router's (it checks)
    port = start_web(spawn, ["--mode", "client", "--connect", endpoint, "--node", "web"], env)
    admin = bus_config(
        "test",
        env={
            "VOXSHAPE_SESSION": "secured",
            "VOXSHAPE_MODE": "client",
            "VOXSHAPE_CONNECT": endpoint,
            "VOXSHAPE_SECRETS": str(secrets),
            "VOXSHAPE_USER": "logger",
        },
    )
    password = dict(
        line.split(":", 1) for line in (secrets / "credentials").read_text().splitlines()
    )["ana"]
    with Node("test", admin) as node:
        node.watch_presence()
        node.input("utterance", teacher_key("secured", "*", "utterance"))
        wait_present(node, "web")
        asyncio.run(secured_browse(port, password, node))


async def secured_browse(port: int, password: str, node: Node) -> None:
    async with aiohttp.ClientSession() as http:
        ws, refused = await open_page(http, port, {"teacher": "ana"})
        assert refused == {
            "type": "refused",
            "reason": "this session is secured: log in with your user name and password",
        }
        ws, refused = await open_page(http, port, {"user": "ana", "password": "wrong"})
        assert refused == {"type": "refused", "reason": REFUSED}  # naming no endpoint
        assert (await ws.receive(timeout=5)).type in (
            aiohttp.WSMsgType.CLOSE,
            aiohttp.WSMsgType.CLOSED,
        )

        # Logged in as ana, it asks to be ben: it is ana, and only ana's words go out.
        ws, welcome = await open_page(
            http, port, {"teacher": "ben", "user": "ana", "password": password}
        )
        assert welcome["type"] == "welcome" and welcome["secured"] and welcome["teacher"] == "ana"
        await ws.send_json({"type": "say", "robot": "r1", "text": "good"})
        (u,) = await asyncio.to_thread(collect, node, 1, Utterance)
        assert (u.teacher, u.text) == ("ana", "good")
        await ws.close()


def test_voxshape_web_stops_cleanly_on_sigterm(spawn, router, session_id):
    port = free_port()
    proc = spawn(
        [VOXSHAPE, "web", *bus_args(router, session_id, "web"), "--port", str(port)], text=True
    )
    wait_for_port(port, timeout=30.0)
    time.sleep(1.0)  # joined the bus
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "serving the page" in err and "Traceback" not in err
    with socket.socket() as busy:  # a port taken: a clear error at once
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        taken_port = busy.getsockname()[1]
        taken = subprocess.run(
            [VOXSHAPE, "web", *bus_args(router, session_id, "web2"), "--port", str(taken_port)],
            capture_output=True,
            text=True,
            timeout=30,
        )
    assert taken.returncode == 2 and "cannot serve the page on 127.0.0.1:" in taken.stderr


@pytest.mark.long
def test_the_demo_with_web_serves_the_page_and_runs_no_simulated_teacher(
    spawn, session_id, tmp_path
):
    web_port = free_port()
    env = {**os.environ, "VOXSHAPE_SESSION": session_id, "VOXSHAPE_WEB_PORT": str(web_port)}
    demo = spawn(
        [VOXSHAPE, "demo", "--web", "--speech", "mock", "--port", str(free_port()),
         "--stall-timeout", "3"],
        env=env,
        text=True,
        stderr=subprocess.STDOUT,
        cwd=tmp_path,
    )  # fmt: skip
    lines = read_until(demo, r"teach it in a browser: |error", timeout=120)
    assert f"teach it in a browser: http://127.0.0.1:{web_port}/ " in lines[-1], lines
    assert any("at 1x real time, taught by you in a browser" in line for line in lines), lines
    assert not any("sim-teacher" in line for line in lines), lines

    async def look() -> None:
        async with aiohttp.ClientSession() as http:
            ws, welcome = await open_page(http, web_port, {"teacher": "ana"})
            assert welcome["type"] == "welcome" and welcome["map"]["name"].startswith("Task 1")
            obs, _ = await until(ws, lambda m: m["type"] == "obs", timeout=60)
            assert obs["robot"] == "r1" and len(obs["laser"]) == 180
            await ws.close()

    asyncio.run(look())
    time.sleep(8)  # at real time an untaught episode lasts longer than the stall timeout ...
    assert demo.poll() is None  # ... and the robot's steps, not its episodes, tell a stall
    demo.send_signal(signal.SIGINT)
    out, _ = demo.communicate(timeout=120)
    assert "no step" not in out and "error" not in out, out


def test_the_page_is_served_over_https_with_the_certificates_voxshape_certs_makes(
    spawn, router, session_id, tmp_path
):
    """Browsers allow the microphone only on localhost or over HTTPS: `voxshape certs` makes
    the router's certificate, which the page serves with; a client trusting the CA gets the
    page and the WebSocket over TLS."""
    secrets = tmp_path / "secrets"
    subprocess.run([VOXSHAPE, "certs", str(secrets)], check=True, capture_output=True)
    https = ["--https-cert", str(secrets / "router.pem")]
    https += ["--https-key", str(secrets / "router.key")]
    port = start_web(spawn, [*bus_args(router, session_id, "web"), *https])
    trusted = ssl.create_default_context(cafile=str(secrets / "ca.pem"))

    async def fetch() -> tuple[int, str, dict]:
        async with aiohttp.ClientSession() as http:
            async with http.get(f"https://localhost:{port}/", ssl=trusted) as page:
                text = await page.text()
            origin = f"https://localhost:{port}"
            ws = await http.ws_connect(f"{origin}/ws", origin=origin, ssl=trusted)
            await ws.send_json({"type": "login", "teacher": "ana", "user": None, "password": None})
            welcome = await ws.receive_json(timeout=15)
            await ws.close()
            return page.status, text, welcome

    status, text, welcome = asyncio.run(fetch())
    assert status == 200 and "<html" in text.lower()
    assert welcome["type"] == "welcome" and welcome["teacher"] == "ana"
    with pytest.raises(aiohttp.ClientConnectorCertificateError):  # not trusted without the CA
        asyncio.run(_get(f"https://localhost:{port}/"))


async def _get(url: str) -> int:
    async with aiohttp.ClientSession() as http, http.get(url) as page:
        return page.status

"""`voxshape web`: a real process on a real bus, driven by a WebSocket client as a browser
would: login, typed words, push-to-talk audio, throttled observations, origins, limits, and a
secured router (its pure core: test_web_gateway.py)."""

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
    Placed,
    Utterance,
    robot_key,
    teacher_key,
)
from voxshape.runtime import Node, bus_config
from voxshape.services.arbiter.scripted import scripted_observation
from voxshape.services.web.gateway import AUDIO_HEADER
from voxshape.services.web.server import REFUSED


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
            self.out.put(scripted_observation("r1", k, time.time()))


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
        await thinned_observations(ws)
        await typed_and_placed(ws, node)
        await push_to_talk(ws, node)
        await limits(ws)
        await ws.close()

        # Another site's page cannot open the socket.
        with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
            await http.ws_connect(f"http://127.0.0.1:{port}/ws", origin="http://evil.example")
        assert refused.value.status == 403
        async with http.get(f"http://127.0.0.1:{port}/") as page:
            assert page.status == 200 and "<html" in (await page.text()).lower()


async def thinned_observations(ws: aiohttp.ClientWebSocketResponse) -> None:
    """At most 10 a second (2 at once), the newest of each slot."""
    await until(ws, lambda m: m["type"] == "obs")
    t0 = time.monotonic()
    _, seen = await until(ws, lambda m: time.monotonic() - t0 > 2.0, timeout=10)
    stamps = [m["stamp"] for m in seen if m["type"] == "obs"]
    # the robot sends 50 a second: some arrive (fewer on a loaded machine), never over 10/s
    assert 2 <= len(stamps) <= 22, len(stamps)
    assert all(c - a >= 99.0 for a, _, c in zip(stamps, stamps[1:], stamps[2:], strict=False))


async def typed_and_placed(ws: aiohttp.ClientWebSocketResponse, node: Node) -> None:
    """A typed word: the arbiter's verdict, as `voxshape teach` shows it; the button of a
    real robot waiting between episodes: it is placed, as ana says."""
    await ws.send_json({"type": "say", "robot": "r1", "text": "good"})
    notice, _ = await until(ws, lambda m: m["type"] == "notice")
    assert notice["kind"] == "understood" and notice["heard"] == "good", notice
    assert notice["text"].endswith("(typed)")
    (u,) = await asyncio.to_thread(collect, node, 1, Utterance)
    assert (u.teacher, u.robot, u.text, u.id) == ("ana", "r1", "good", notice["utterance"])
    await ws.send_json({"type": "placed", "robot": "r1"})
    (placed,) = await asyncio.to_thread(collect, node, 1, Placed)
    assert (placed.teacher, placed.robot) == ("ana", "r1")


async def push_to_talk(ws: aiohttp.ClientWebSocketResponse, node: Node) -> None:
    """Push-to-talk with a browser clock 5 s behind the gateway's: chunks on its clock."""
    skew = 5000.0
    await ws.send_json({"type": "clock", "t0": time.time() * 1000 - skew})
    reply, _ = await until(ws, lambda m: m["type"] == "clock")
    assert skew <= reply["offset_ms"] < 2 * skew, reply  # 5 s behind, plus the trip
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


async def limits(ws: aiohttp.ClientWebSocketResponse) -> None:
    """Oversize and too-fast frames: an error each, and the page goes on."""
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

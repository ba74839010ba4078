"""The teachers' page against a hostile browser, on a real gateway, router and arbiter: each
attack is refused or limited, the gateway logs no traceback, and a teacher already on the page
is still understood, not held up, after each (docs/web.md#security)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import resource
import subprocess
import time
from pathlib import Path

import aiohttp
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.conftest import VOXSHAPE, free_port, wait_for_port, wait_present, web_log_path
from tests.test_web import Robot, open_page, until
from tests.web_strangers import (
    NOT_HELD_UP_S,
    STRANGERS,
    WAITED,
    ana_on_the_page,
    connect,
    from_address,
    guess,
    raw,
    teachers_still_teach,
    understood,
)
from voxshape.runtime import Node, bus_config
from voxshape.services.web.gateway import AUDIO_HEADER
from voxshape.services.web.server import REFUSED

SESSION = "secured"


def passwords(secrets: Path) -> dict[str, str]:
    lines = (secrets / "credentials").read_text().splitlines()
    return dict(line.split(":", 1) for line in lines)


def web_log(port: int) -> str:
    return (web_log_path(port)).read_text()


@pytest.fixture
def session(spawn, secured):
    """A secured session: router, arbiter, a robot's observations, and `voxshape web`
    (started with a low file limit, to meet its connection budget). Yields the page's port,
    the passwords and the admin's node."""
    endpoint, secrets = secured
    env = {**os.environ, "VOXSHAPE_SESSION": SESSION, "VOXSHAPE_SECRETS": str(secrets)}
    bus = ["--mode", "client", "--connect", endpoint]
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    spawn([VOXSHAPE, "arbiter", *bus, "--node", "arbiter"], env=env, **quiet)
    port = free_port()
    log = web_log_path(port)
    with log.open("w") as out:
        spawn(
            [VOXSHAPE, "web", *bus, "--node", "web", "--port", str(port)],
            stdout=out,
            stderr=subprocess.STDOUT,
            env={**env, "VOXSHAPE_ACCESS": str(secrets / "access.toml")},
            preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_NOFILE, (400, 400)),
        )
    wait_for_port(port, timeout=30.0)
    admin = bus_config(
        "test",
        env={
            "VOXSHAPE_SESSION": SESSION,
            "VOXSHAPE_MODE": "client",
            "VOXSHAPE_CONNECT": endpoint,
            "VOXSHAPE_SECRETS": str(secrets),
            "VOXSHAPE_USER": "logger",
        },
    )
    with Node("test", admin) as node:
        node.watch_presence()
        wait_present(node, {"arbiter", "web"})
        robot = Robot(node, SESSION)
        robot.start()
        try:
            yield port, passwords(secrets)
        finally:
            robot.stopping.set()
            robot.join(5)
    assert "Traceback" not in web_log(port)


@pytest.mark.long
def test_strangers_cannot_lock_out_guess_or_outrun_a_teacher(session):
    port, password = session
    asyncio.run(attacks(port, password))


async def attacks(port: int, password: dict[str, str]) -> None:
    page = f"http://127.0.0.1:{port}"
    took: dict[str, float] = {}
    async with aiohttp.ClientSession() as http:
        ana, welcome = await open_page(http, port, {"user": "ana", "password": password["ana"]})
        assert welcome["type"] == "welcome", welcome
        await until(ana, lambda m: m["type"] == "obs")
        await asyncio.sleep(2.0)  # the arbiter has a second of the robot's steps
        took["before"] = await understood(ana)
        await guessing_one_at_a_time(http, port, password)
        took["guessing"] = await understood(ana)
        took["idle sockets"] = await idle_sockets(http, ana, page)
        ben, welcome = await open_page(http, port, {"user": "ben", "password": password["ben"]})
        assert welcome["type"] == "welcome", welcome

        # One teacher's tabs: three at most.
        tabs = [
            (await open_page(http, port, {"user": "ana", "password": password["ana"]}))
            for _ in range(3)
        ]
        assert [t[1]["type"] for t in tabs] == ["welcome", "welcome", "refused"]
        assert "ana has 3 pages open already" in tabs[2][1]["reason"]
        for ws, _ in tabs:
            await ws.close()

        # Audio faster than real time: refused beyond a 3 s burst.
        await ben.send_json({"type": "talk", "robot": "r1", "state": "start"})
        for _ in range(40):  # 40 s of audio at once
            await ben.send_bytes(AUDIO_HEADER.pack(time.time() * 1000) + bytes(32_000))
        error, _ = await until(ben, lambda m: m["type"] == "error")
        assert "faster than real time" in error["text"]
        await ben.send_json({"type": "talk", "robot": "r1", "state": "stop"})
        took["audio flood"] = await understood(ana)

        # DNS rebinding: another name for this address is refused, page and socket.
        async with http.get(f"{page}/", headers={"Host": f"evil.example:{port}"}) as r:
            assert r.status == 403
        with pytest.raises(aiohttp.WSServerHandshakeError) as rebound:
            await http.ws_connect(
                f"{page}/ws",
                origin=f"http://evil.example:{port}",
                headers={"Host": f"evil.example:{port}"},
            )
        assert rebound.value.status == 403
        async with http.get(f"{page}/") as r:
            assert r.status == 200 and r.headers["Server"] == "voxshape"

        took |= await connection_floods(http, ana, port, password["cy"])
        async with http.get(f"{page}/") as r:
            assert r.status == 200
        took["after"] = await understood(ana)
        await ana.close()
        await ben.close()
    print("WEB-ATTACK-FIGURES", json.dumps({k: round(v, 3) for k, v in took.items()}))
    closing = took.pop("300 connections closed")
    assert closing <= 15.0 and max(took.values()) <= NOT_HELD_UP_S, took
    log = web_log(port)
    assert log.count("connections gave way: the budget is spent") == 1, log[-3000:]
    assert log.count("refused connections: too many from one address") == 1, log[-3000:]
    assert 'peer=127.0.0.1 why="not a teacher"' in log


async def guessing_one_at_a_time(
    http: aiohttp.ClientSession, port: int, password: dict[str, str]
) -> None:
    """The bus's admin accounts are not teachers; a guess gets the same refusal whatever
    failed, naming no endpoint; after three failures, each next try must wait longer."""
    ws, refused = await open_page(http, port, {"user": "logger", "password": password["logger"]})
    assert refused == {"type": "refused", "reason": REFUSED}
    await ws.close()

    replies = []
    for k in range(5):
        ws, refused = await open_page(http, port, {"user": "ben", "password": f"x{k}"})
        replies.append(refused["reason"])
        await ws.close()
    assert replies[:2] == [REFUSED] * 2, replies
    assert f"{REFUSED} (wait a few seconds)" in replies[2:], replies
    assert all(r.startswith(REFUSED) and "tcp/" not in r for r in replies)
    ws, refused = await open_page(http, port, {"user": "ghost", "password": "x"})
    assert refused["reason"].startswith(REFUSED)  # an unknown user: the same
    await ws.close()


async def idle_sockets(
    http: aiohttp.ClientSession, ana: aiohttp.ClientWebSocketResponse, page: str
) -> float:
    """Sockets that never log in wait in a room of their own: refused beyond it (8 of one
    address), told and closed after 5 s; meanwhile the teacher on the page is understood
    (the seconds it took)."""
    idle = [await http.ws_connect(f"{page}/ws", origin=page) for _ in range(8)]
    with pytest.raises(aiohttp.WSServerHandshakeError) as full:
        await http.ws_connect(f"{page}/ws", origin=page)
    assert full.value.status == 503
    took = await understood(ana)
    for ws in idle:
        assert (await ws.receive(timeout=8)).type == aiohttp.WSMsgType.TEXT  # "log in"
        assert (await ws.receive(timeout=2)).type in (
            aiohttp.WSMsgType.CLOSE,
            aiohttp.WSMsgType.CLOSED,
        )
    return took


async def connection_floods(
    http: aiohttp.ClientSession, ana: aiohttp.ClientWebSocketResponse, port: int, cy: str
) -> dict[str, float]:
    """Idle and half-sent connections are closed; one address holds a quarter of the budget
    at most; past the budget, the oldest that are no teacher's give way. A teacher logging
    in during either flood gets in; those on the page go on."""
    took = {}
    opened = time.monotonic()
    conns = [connect(port, "127.0.0.2") for _ in range(100)]
    fresh = {"user": "cy", "password": cy}
    flooded, _ = await teachers_still_teach(http, ana, port, fresh)
    took["one address's flood: fresh"] = flooded["fresh"]
    conns += [connect(port, f"127.0.0.{3 + k // 25}") for k in range(200)]
    for c in conns[-50:]:
        with contextlib.suppress(OSError):  # unless it gave way already
            c.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")  # and never the rest
    flooded, _ = await teachers_still_teach(http, ana, port, fresh)
    took["many addresses' flood: fresh"] = flooded["fresh"]
    took["idle connections"] = await understood(ana)
    deadline, closed = time.monotonic() + 15, 0
    for c in conns:
        c.settimeout(max(0.1, deadline - time.monotonic()))
        try:
            closed += c.recv(1024) == b""  # the gateway closed it
        except ConnectionResetError:
            closed += 1
        except TimeoutError:
            pass
        finally:
            c.close()
    assert closed == len(conns)
    took["300 connections closed"] = time.monotonic() - opened
    return took


@settings(
    max_examples=40,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(data=st.data())
def test_fuzzed_frames_leave_the_socket_served_and_log_no_traceback(session, data):
    port, password = session
    json_values = st.recursive(
        st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20),
        lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner),
        max_leaves=20,
    )
    frame = st.one_of(
        st.fixed_dictionaries(
            {"type": st.sampled_from(["say", "clock", "talk", "watch", "login", "x"])},
            optional={
                k: json_values
                for k in ("text", "t0", "onset", "offset_ms", "rtt_ms", "state", "robot")
            },
        ).map(json.dumps),
        st.text(max_size=200),
        st.binary(max_size=300),
    )
    frames = data.draw(st.lists(frame, min_size=1, max_size=10))
    asyncio.run(fuzz(port, password["ana"], frames))


async def fuzz(port: int, password: str, frames: list) -> None:
    async with aiohttp.ClientSession() as http:
        ws, welcome = await open_page(http, port, {"user": "ana", "password": password})
        assert welcome["type"] == "welcome", welcome
        for f in frames:
            await (ws.send_bytes(f) if isinstance(f, bytes) else ws.send_str(f))
        await ws.send_json({"type": "clock", "t0": time.time() * 1000})
        await until(ws, lambda m: m["type"] == "clock")  # the socket is still served
        await ws.close()


def test_requests_that_are_no_websocket_take_no_place_in_the_waiting_room(session):
    port, password = session
    asyncio.run(no_websockets(port, password))


async def no_websockets(port: int, password: dict[str, str]) -> None:
    page = f"http://127.0.0.1:{port}"
    key = "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
    handshake = f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nOrigin: {page}\r\n"
    handshake += "Upgrade: websocket\r\nConnection: Upgrade\r\n"
    async with aiohttp.ClientSession() as http:
        ana = await ana_on_the_page(http, port, password["ana"])

        async def plain_gets(address: str) -> list[int]:
            async with from_address(address) as stranger:
                statuses = []
                for _ in range(10):
                    async with stranger.get(f"{page}/ws", headers={"Origin": page}) as r:
                        statuses.append(r.status)
                return statuses

        # 90 plain GETs of /ws with the page's Origin, from 9 addresses: 400, no place taken.
        statuses = await asyncio.gather(*(plain_gets(a) for a in STRANGERS[:9]))
        assert {s for each in statuses for s in each} == {400}, statuses
        # Broken handshakes (a bad key, an unknown version) and clients that leave midway.
        broken = [
            handshake + "Sec-WebSocket-Version: 13\r\nSec-WebSocket-Key: short\r\n\r\n",
            handshake + f"Sec-WebSocket-Version: 12\r\n{key}\r\n",
        ]
        for address in STRANGERS[9:18]:
            for request in broken:
                assert (await raw(address, port, request.encode())).startswith(b"HTTP/1.1 400")
            whole = handshake + f"Sec-WebSocket-Version: 13\r\n{key}\r\n"
            for _ in range(9):  # a whole handshake, then gone before the answer
                await raw(address, port, whole.encode(), answer=False)
            await raw(address, port, whole[:60].encode(), answer=False)  # gone midway
        await asyncio.sleep(0.5)
        ben = {"user": "ben", "password": password["ben"]}
        took, _ = await teachers_still_teach(http, ana, port, ben)
        await ana.close()
    print("WEB-NO-WEBSOCKET-FIGURES", json.dumps({k: round(v, 3) for k, v in took.items()}))


@pytest.mark.long
def test_a_stranger_failing_as_a_teacher_never_locks_her_out(session):
    port, password = session
    asyncio.run(stranger_fails_as_cy(port, password))


async def stranger_fails_as_cy(port: int, password: dict[str, str]) -> None:
    async with aiohttp.ClientSession() as http, from_address("127.0.0.1") as cy:
        ana = await ana_on_the_page(http, port, password["ana"])
        # Six wrong passwords as cy from another address, waiting as told between them.
        failures, tries = 0, 0
        while failures < 6 and tries < 40:
            tries += 1
            reason = await guess(STRANGERS[0], port, "cy", "not-hers")
            failures += reason == REFUSED
            if reason == WAITED:
                await asyncio.sleep(1.0)
        assert failures == 6, (failures, tries)
        # cy logs in from her own address, without a device cookie yet: she is let in, and
        # the page's device token becomes her browser's cookie.
        login = {"user": "cy", "password": password["cy"]}
        took, welcome = await teachers_still_teach(cy, ana, port, login)
        origin = f"http://127.0.0.1:{port}"
        device = {"data": welcome["device"], "headers": {"Origin": origin}}
        async with cy.post(f"{origin}/ws/device", **device) as r:
            assert r.status == 204, await r.text()
            cookie = r.headers["Set-Cookie"]
        for attribute in ("voxshape-device-cy=", "HttpOnly", "SameSite=Strict", "Path=/ws"):
            assert attribute in cookie, cookie
        # Strangers fail as cy from 11 addresses at once: browsers without her cookie must
        # wait now (guessing from many addresses is held up), hers is not.
        reasons = await asyncio.gather(
            *(guess(a, port, "cy", f"x{k}") for k, a in enumerate(STRANGERS[1:12]))
        )
        assert (reasons.count(REFUSED), reasons.count(WAITED)) == (10, 1), reasons
        assert await guess(STRANGERS[20], port, "cy", password["cy"]) == WAITED
        with_cookie, _ = await teachers_still_teach(cy, ana, port, login)
        took |= {f"{k} (cookie)": v for k, v in with_cookie.items()}
        # A token altered, or from another page, is not made a cookie; nor from elsewhere.
        forged = {**device, "data": welcome["device"].replace("cy:", "ben:", 1)}
        elsewhere = {**device, "headers": {"Origin": "http://evil.example"}}
        for attempt, status in ((forged, 400), (elsewhere, 403)):
            async with cy.post(f"{origin}/ws/device", **attempt) as r:
                assert r.status == status
        await ana.close()
    print("WEB-STRANGER-FIGURES", json.dumps({k: round(v, 3) for k, v in took.items()}))


def test_guesses_sent_at_once_are_counted_before_the_router_answers(session):
    port, password = session
    asyncio.run(guesses_at_once(port, password))


async def guesses_at_once(port: int, password: dict[str, str]) -> None:
    async with aiohttp.ClientSession() as http:
        ana = await ana_on_the_page(http, port, password["ana"])

        # 30 wrong guesses as ben at once, from 30 addresses: 10 reach the router (ben's key
        # for browsers without his cookie), the rest are refused at once; a teacher logging
        # in meanwhile does not wait behind the router's checks of them.
        async def meanwhile() -> float:
            await asyncio.sleep(0.2)  # the guesses are being checked
            opened = time.monotonic()
            ws, welcome = await open_page(http, port, {"user": "cy", "password": password["cy"]})
            assert welcome["type"] == "welcome", welcome
            await ws.close()
            return time.monotonic() - opened

        *reasons, login_s = await asyncio.gather(
            *(guess(a, port, "ben", f"x{k}") for k, a in enumerate(STRANGERS[:30])), meanwhile()
        )
        assert (reasons.count(REFUSED), reasons.count(WAITED)) == (10, 20), reasons
        assert login_s <= NOT_HELD_UP_S, login_s
        # 8 at once as cy from one address (all its waiting room holds): 3 reach the router.
        reasons = await asyncio.gather(
            *(guess(STRANGERS[40], port, "cy", f"y{k}") for k in range(8))
        )
        assert (reasons.count(REFUSED), reasons.count(WAITED)) == (3, 5), reasons
        asked = web_log(port).count("a browser's login was refused")
        assert asked == 13, web_log(port)[-3000:]  # what the router was asked, no more
        took, _ = await teachers_still_teach(
            http, ana, port, {"user": "cy", "password": password["cy"]}
        )
        await ana.close()
    took["login during the guesses"] = login_s
    print("WEB-AT-ONCE-FIGURES", json.dumps({k: round(v, 3) for k, v in took.items()}))


def test_idle_sockets_from_many_addresses_give_way_to_a_teacher(session):
    port, password = session
    asyncio.run(idle_from_many(port, password))


async def idle_from_many(port: int, password: dict[str, str]) -> None:
    page = f"http://127.0.0.1:{port}"
    strangers = [from_address(a) for a in STRANGERS[:9]]
    try:
        async with aiohttp.ClientSession() as http:
            ana = await ana_on_the_page(http, port, password["ana"])
            # 72 sockets that never log in, 8 from each of 9 addresses: the room holds 64, the
            # oldest give way (told so); a teacher logging in now gets in.
            idle = [
                await s.ws_connect(f"{page}/ws", origin=page) for s in strangers for _ in range(8)
            ]
            ben = {"user": "ben", "password": password["ben"]}
            took, _ = await teachers_still_teach(http, ana, port, ben)
            gave_way = 0
            for ws in idle[:9]:
                msg = await ws.receive(timeout=5)
                gave_way += msg.type == aiohttp.WSMsgType.TEXT and "waited longest" in msg.data
            assert gave_way == 9, gave_way  # 8 for the strangers' 9th address, 1 for ben
            await ana.close()
    finally:
        for s in strangers:
            await s.close()
    print("WEB-IDLE-FIGURES", json.dumps({k: round(v, 3) for k, v in took.items()}))

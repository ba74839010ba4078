"""Strangers and teachers of the page's attack tests (tests/test_web_attacks.py): browsers at
other loopback addresses (127.0.0.0/8 is all this host's), raw requests, and the checks that a
teacher already on the page and one logging in are both still understood (within a second on
an idle machine: the figures are printed; a test checks they are not held up)."""

from __future__ import annotations

import asyncio
import socket
import statistics
import time

import aiohttp

from tests.test_web import open_page, until
from voxshape.services.web.server import REFUSED

# Other addresses are loopback ones: 127.0.0.0/8 is all this host's. The teachers are on
# 127.0.0.1; each attack comes from others.
STRANGERS = [f"127.0.0.{k}" for k in range(2, 80)]
WAITED = f"{REFUSED} (wait a few seconds)"
# A teacher held up by an attack waits for its timeouts (10 s and more); under 1 s on an idle
# machine (WEB-ATTACK-FIGURES), a loaded one may take a few: not a figure a test can judge.
NOT_HELD_UP_S = 5.0


def from_address(address: str) -> aiohttp.ClientSession:
    """A browser at `address`, keeping cookies as a browser does (of an IP address too)."""
    return aiohttp.ClientSession(
        connector=aiohttp.TCPConnector(local_addr=(address, 0), force_close=True),
        cookie_jar=aiohttp.CookieJar(unsafe=True),
    )


async def guess(address: str, port: int, user: str, password: str) -> str:
    """One login from `address`: the refusal's reason ("welcome" if it got in)."""
    async with from_address(address) as http:
        ws, reply = await open_page(http, port, {"user": user, "password": password})
        await ws.close()
    return reply.get("reason", reply["type"])


async def raw(address: str, port: int, request: bytes, answer: bool = True) -> bytes:
    """A request as bytes from `address`; the status line of the answer (if waited for)."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port, local_addr=(address, 0))
    writer.write(request)
    await writer.drain()
    status = await asyncio.wait_for(reader.readline(), 10) if answer else b""
    writer.close()
    return status


async def teachers_still_teach(
    http: aiohttp.ClientSession, ana: aiohttp.ClientWebSocketResponse, port: int, login: dict
) -> tuple[dict[str, float], dict]:
    """The teacher already on the page (ana) and one logging in now (`login`, through `http`)
    are both understood, not held up (the median of three words each); the seconds, and the
    welcome."""
    opened = time.monotonic()
    ws, welcome = await open_page(http, port, login)
    assert welcome["type"] == "welcome", welcome
    took = {"login": time.monotonic() - opened, "fresh": await understood(ws)}
    took["on the page"] = await understood(ana)
    await ws.close()
    assert max(took.values()) <= NOT_HELD_UP_S, took
    return took, welcome


async def ana_on_the_page(http: aiohttp.ClientSession, port: int, password: str):
    ana, welcome = await open_page(http, port, {"user": "ana", "password": password})
    assert welcome["type"] == "welcome", welcome
    await until(ana, lambda m: m["type"] == "obs")
    await asyncio.sleep(2.0)  # the arbiter has a second of the robot's steps
    return ana


async def understood(ws: aiohttp.ClientWebSocketResponse, words: int = 3) -> float:
    """Says "good" `words` times and waits for each verdict (past a "no answer within 1 s"
    line); the median of the seconds they took: one word held up by a busy machine's
    scheduler does not decide, an attack that holds the teacher up does."""
    took = []
    for _ in range(words):
        start = time.monotonic()
        await ws.send_json({"type": "say", "robot": "r1", "text": "good"})
        notice, _ = await until(
            ws, lambda m: m["type"] == "notice" and m["kind"] != "no_answer", timeout=10
        )
        assert notice["kind"] == "understood", notice
        took.append(time.monotonic() - start)
        await asyncio.sleep(0.3)  # within the arbiter's rate: 4 words a second, 8 at once
    return statistics.median(took)


def connect(port: int, address: str) -> socket.socket:
    """A TCP connection to the page from `address` (a loopback one)."""
    return socket.create_connection(("127.0.0.1", port), source_address=(address, 0))

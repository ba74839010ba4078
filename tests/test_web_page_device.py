"""The device cookie in a real headless Chromium (Debian's, driven by Playwright) against a real
secured router and `voxshape web`: after a login the browser keeps it (HttpOnly, SameSite
Strict, only for /ws), sends it back with the next login's handshake, and so gets in while
strangers failing as its teacher from many addresses hold up every other browser."""

from __future__ import annotations

import asyncio
import os
import subprocess
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import aiohttp
import pytest

from tests.conftest import VOXSHAPE, bus_args, free_port, wait_for_port
from tests.test_web import open_page
from tests.test_web_page import BROWSER_ARGS, CHROMIUM, SECURED_ACCESS, WAIT_MS, Processes
from voxshape.deploy.access import load_access, load_credentials
from voxshape.deploy.certs import make_all
from voxshape.launcher import router_command
from voxshape.services.web.server import REFUSED

sync_api = pytest.importorskip("playwright.sync_api", reason="Playwright is a dev dependency")
pytestmark = [
    pytest.mark.skipif(
        not CHROMIUM.exists(),
        reason="Debian's chromium is missing (/usr/bin/chromium): no browser is downloaded",
    ),
    pytest.mark.timeout(180),
]


@pytest.fixture
def secured_page(tmp_path) -> Iterator[tuple[str, dict[str, str], Path]]:
    """A secured router and its page; the page's address, the passwords and the page's log."""
    (tmp_path / "access.toml").write_text(SECURED_ACCESS)
    make_all(tmp_path, load_access(tmp_path / "access.toml"))
    port, web_port = free_port(), free_port()
    router = f"tcp/127.0.0.1:{port}"
    secrets = ("--secrets", str(tmp_path))
    access = ("--access", str(tmp_path / "access.toml"))
    procs = Processes()
    log = tmp_path / "web.log"
    try:
        named = ("--session", "locked", "--node", "router", "--listen", router)
        procs.start(router_command(*named, *secrets, *access), tmp_path)
        wait_for_port(port)
        with log.open("w") as out:
            bus = (*bus_args(router, "locked", "web"), "--user", "web", *secrets, *access)
            proc = subprocess.Popen(
                [VOXSHAPE, "web", *bus, "--port", str(web_port)],
                cwd=tmp_path,
                stdout=out,
                stderr=subprocess.STDOUT,
            )
        procs.children.append(proc)
        wait_for_port(web_port, timeout=30)
        yield f"http://127.0.0.1:{web_port}/", load_credentials(tmp_path / "credentials"), log
    finally:
        procs.stop()


async def strangers_fail_as(port: int, user: str, addresses: list[str]) -> list[str]:
    async def one(address: str) -> str:
        connector = aiohttp.TCPConnector(local_addr=(address, 0), force_close=True)
        async with aiohttp.ClientSession(connector=connector) as http:
            ws, reply = await open_page(http, port, {"user": user, "password": "wrong"})
            await ws.close()
        return reply.get("reason", reply["type"])

    return await asyncio.gather(*(one(a) for a in addresses))


def fill_login(page, url: str, password: str) -> None:
    page.goto(url, timeout=WAIT_MS)
    page.fill("#user", "ana")
    page.fill("#password", password)


def log_in(page, url: str, password: str) -> None:
    fill_login(page, url, password)
    page.click("#login-button")


@pytest.mark.long
def test_the_browser_keeps_its_device_cookie_and_gets_in_while_strangers_guess(secured_page):
    url, passwords, log = secured_page
    port = int(url.rsplit(":", 1)[1].strip("/"))
    with sync_api.sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=str(CHROMIUM), args=BROWSER_ARGS)
        try:
            hers = chromium.new_context(bypass_csp=True)  # wait_for_function evaluates
            page = hers.new_page()
            log_in(page, url, passwords["ana"])
            page.wait_for_function("window.voxshape.device !== null", timeout=WAIT_MS)
            assert page.evaluate("window.voxshape.device") == "kept"
            (cookie,) = [c for c in hers.cookies() if c["name"] == "voxshape-device-ana"]
            assert (cookie["httpOnly"], cookie["sameSite"], cookie["path"]) == (
                True,
                "Strict",
                "/ws",
            ), cookie
            assert "voxshape-device" not in page.evaluate("document.cookie")  # not to scripts
            page.close()
            # Another browser, ready to log in as soon as the strangers have failed: their
            # failures hold it up for 1 s (a loaded machine opens a page slower than that).
            other = chromium.new_context(bypass_csp=True).new_page()
            fill_login(other, url, passwords["ana"])
            # Strangers fail as ana from 11 addresses: browsers without her cookie must wait.
            strangers = [f"127.0.0.{k}" for k in range(2, 13)]
            with ThreadPoolExecutor(1) as aside:  # Playwright's loop runs in this thread
                reasons = aside.submit(asyncio.run, strangers_fail_as(port, "ana", strangers))
                reasons = reasons.result(timeout=60)
            other.click("#login-button")
            assert reasons.count(REFUSED) == 10, reasons
            other.wait_for_function("window.voxshape.refused !== null", timeout=WAIT_MS)
            assert "wait a few seconds" in other.evaluate("window.voxshape.refused")
            # Her browser sends its cookie with the socket's handshake: she gets in.
            page = hers.new_page()
            log_in(page, url, passwords["ana"])
            page.wait_for_function("window.voxshape.phase === 'teaching'", timeout=WAIT_MS)
        finally:
            chromium.close()
    logged_in = [line for line in log.read_text().splitlines() if "a browser logged in" in line]
    assert [("device=True" in line) for line in logged_in] == [False, True], logged_in
    assert os.path.getsize(log) > 0 and "Traceback" not in log.read_text()

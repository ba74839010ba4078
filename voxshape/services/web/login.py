"""A socket's login on the page's server: its first frame (or it gives way, or times out), the
throttle, the teachers of the access file, the router (the browser's own teacher node, opened
with its user and password), a teacher's place, and the welcome with a device token; and the
endpoint that turns a device token into the browser's HttpOnly cookie (docs/web.md#security).
"""

from __future__ import annotations

import asyncio
import json
import logging
import ssl
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

from aiohttp import WSMessage, WSMsgType, web

from voxshape.protocol import TeacherNotice, Utterance
from voxshape.runtime import BusConfig, BusError, ConfigError, Input, Node, fields
from voxshape.runtime.limits import TokenBucket
from voxshape.services.web.admission import Admission, LoginThrottle, Origins, login_keys
from voxshape.services.web.browser import Browser, Pump
from voxshape.services.web.connections import Budget
from voxshape.services.web.devices import COOKIE_PATH, DeviceTokens, cookie_name
from voxshape.services.web.frames import BrowserError, Login, parse_frame, parse_login
from voxshape.services.web.gateway import AUDIO_BURST_S, Teaching
from voxshape.services.web.page_json import SessionView
from voxshape.services.web.robots import Robots
from voxshape.teaching.board import ANSWER_WITHIN_S, Board
from voxshape.teaching.joining import join_as_teacher

LOGIN_WAIT_S = 5.0  # a socket that has not logged in by then is closed
REFUSED = "login refused: wrong user name or password, or not a teacher of this session"
GAVE_WAY = "too many pages were logging in at once: this one waited longest; join again"
_CLOSING = (WSMsgType.CLOSE, WSMsgType.CLOSING, WSMsgType.CLOSED, WSMsgType.ERROR)


class LoginFlow:
    """The PageServer's logins (a part of it: the PageServer sets these attributes)."""

    bus: BusConfig
    view: SessionView
    tls: ssl.SSLContext | None
    origins: Origins
    admission: Admission
    budget: Budget
    throttle: LoginThrottle
    checking: ThreadPoolExecutor  # logins being checked by the router (a wrong one: ~1.2 s)
    devices: DeviceTokens
    teachers: frozenset[str] | None  # who may log in (None: anyone, open)
    audio: dict[str, TokenBucket]
    robots: Robots
    logins: int
    loop: asyncio.AbstractEventLoop | None
    log: logging.Logger

    async def _login(self, browser: Browser) -> bool:
        """The first message: log in, open this teacher's node, welcome. False: refused."""
        msg = await self._first_frame(browser)
        self.admission.leave(browser)  # out of the waiting room, whatever it sent
        if msg is None or msg.type in _CLOSING:
            return False
        if msg.type != WSMsgType.TEXT:
            return await self._refuse(browser, "log in first")
        try:
            login = parse_login(parse_frame(msg.data), self.view.secured)
        except BrowserError as e:
            return await self._refuse(browser, str(e))
        keys = self._throttle_keys(browser, login)
        # Counted as failed now, before the router is asked: guesses sent at once are counted.
        if (wait := self.throttle.attempt(keys, time.monotonic())) > 0:
            self.log.warning(
                "a login came too soon after failed ones",
                extra=fields(user=login.user, peer=browser.peer, wait_s=round(wait, 1)),
            )
            return await self._refuse(browser, f"{REFUSED} (wait a few seconds)")
        if self.teachers is not None and login.teacher not in self.teachers:
            return await self._login_failed(browser, login.teacher, keys, "not a teacher")
        self.logins += 1
        node_id = f"web-{login.teacher}"[:56] + f"-{self.logins}"
        config = replace(self.bus, node=node_id, user=login.user, password=login.password)
        assert self.loop is not None
        try:  # in threads of the logins' own: the bus's work never waits behind them
            await self.loop.run_in_executor(
                self.checking, self._teacher_node, browser, login.teacher, config
            )
        except (BusError, ConfigError) as e:
            return await self._login_failed(browser, login.teacher, keys, str(e))
        self.throttle.succeeded(keys)  # the password was right, whatever comes next
        refusal = self.admission.login(login.teacher)
        if refusal is not None:
            return await self._refuse(browser, refusal)
        browser.user = login.teacher
        self.budget.prove(browser.transport)  # a teacher's connection never gives way
        self._welcome(browser, login, device=any(k.startswith("device:") for k in keys))
        return True

    async def _first_frame(self, browser: Browser) -> WSMessage | None:
        """Its first frame; None (told why) if it gave way in a full waiting room or sent
        nothing within LOGIN_WAIT_S."""
        receiving = asyncio.ensure_future(browser.ws.receive())
        evicted = asyncio.ensure_future(browser.evicted.wait())
        try:
            done, _ = await asyncio.wait(
                (receiving, evicted), timeout=LOGIN_WAIT_S, return_when=asyncio.FIRST_COMPLETED
            )
        finally:
            receiving.cancel()
            evicted.cancel()
        if receiving in done:
            return receiving.result()
        reason = GAVE_WAY if evicted in done else f"log in within {LOGIN_WAIT_S:g} s"
        await self._refuse(browser, reason)
        return None

    def _throttle_keys(self, browser: Browser, login: Login) -> tuple[str, ...]:
        """Its keys (admission.login_keys): none on an open session, where nobody guesses."""
        if not self.view.secured or login.user is None:
            return ()
        device = self.devices.verify(browser.cookies.get(cookie_name(login.user)), time.time())
        teacher = self.teachers is None or login.user in self.teachers
        nonce = device.nonce if device is not None and device.user == login.user else None
        return login_keys(login.user, browser.address, teacher, nonce)

    def _welcome(self, browser: Browser, login: Login, device: bool) -> None:
        """Its teaching state and the welcome; `device`: it came with its device cookie."""
        board = Board(
            answer_within_s=ANSWER_WITHIN_S,
            no_answer_hint=f"no arbiter in session {self.view.session!r} heard it",
        )
        budget = self.audio.setdefault(login.teacher, TokenBucket(1.0, AUDIO_BURST_S))
        browser.teaching = Teaching(login.teacher, self.robots, board, self.view.language, budget)
        welcome = self.robots.welcome(self.view, login.teacher, time.time())
        if self.view.secured:  # the page keeps it as a cookie: /ws/device
            welcome["device"] = self.devices.issue(login.teacher, time.time())
        browser.send(welcome)
        assert browser.node is not None
        self.log.info(
            "a browser logged in",
            extra=fields(
                teacher=login.teacher, node=browser.node.id, peer=browser.peer, device=device
            ),
        )

    async def _login_failed(
        self, browser: Browser, user: str, keys: tuple[str, ...], why: str
    ) -> bool:
        """The same refusal for every failure (the log says which); the throttle's wait runs
        from now."""
        self.throttle.failed(keys, time.monotonic())
        self.log.warning(
            "a browser's login was refused", extra=fields(user=user, peer=browser.peer, why=why)
        )
        return await self._refuse(browser, REFUSED)

    def _teacher_node(self, browser: Browser, teacher: str, config: BusConfig) -> None:
        """In a thread (the login can take a second): this browser's own teacher node. Its
        audio is not kept: a browser's chunks are a second long, 800 of them too many."""
        node = Node("teacher", config)
        browser.node = node
        browser.outputs = join_as_teacher(
            node,
            browser.stack,
            teacher,
            ("utterance", "audio", "placed"),
            synced=lambda e: None,
            problem=lambda text: node.log.info(f"clock exchange: {text}"),
            kept={"audio": 0},
        )
        assert self.loop is not None
        pump = Pump(node, self.loop, lambda event: self._on_teacher(browser, event))
        browser.stack.callback(pump.stop)

    def _on_teacher(self, browser: Browser, event: object) -> None:
        if browser.teaching is None or not isinstance(event, Input):
            return
        now = time.monotonic()
        lines = []
        if isinstance(event.message, TeacherNotice):
            lines = browser.teaching.notice(event.message, now)
        elif isinstance(event.message, Utterance):
            lines = browser.teaching.recognized(event.message, now)
        for line in lines:
            browser.send(line)

    async def _refuse(self, browser: Browser, reason: str) -> bool:
        """Says why, then closes the socket. Always False (not logged in)."""
        with_reason = json.dumps({"type": "refused", "reason": reason})
        try:
            await browser.ws.send_str(with_reason)
            await browser.ws.close(code=1008, message=b"refused")
        except (ConnectionError, RuntimeError):
            pass
        return False

    async def _device(self, request: web.Request) -> web.StreamResponse:
        """POST /ws/device, the welcome's device token: answered with it as an HttpOnly,
        SameSite=Strict cookie (Secure over HTTPS), sent back with the socket's handshake."""
        scheme = "https" if self.tls is not None else "http"
        if not self.origins.origin_allowed(request.headers.get("Origin"), request.host, scheme):
            raise web.HTTPForbidden(text="this is for the page's own origin")
        token = (await request.text()).strip()
        device = self.devices.verify(token, time.time())
        if device is None:
            raise web.HTTPBadRequest(text="not a device token of this page (the welcome's)")
        response = web.Response(status=204)
        secure = self.tls is not None or (self.origins.public or "").startswith("https:")
        response.set_cookie(
            cookie_name(device.user),
            token,
            max_age=self.devices.age_left(device, time.time()),
            path=COOKIE_PATH,
            httponly=True,
            samesite="Strict",
            secure=secure,
        )
        return response

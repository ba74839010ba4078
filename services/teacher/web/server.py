"""The page's server: the aiohttp application, one Browser per socket (its queue, its
teacher node), and the Gateway between them and the bus.

Zenoh delivers on its own threads: a pump thread per node hands each message to the event
loop (call_soon_threadsafe); a browser is sent from a bounded queue of its own, observations
aside (only each robot's latest waits), so a slow browser never holds up the bus.
"""

from __future__ import annotations

import asyncio
import json
import logging
import signal
import ssl
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path
from typing import Any

from aiohttp import WSMsgType, web

from protocol import (
    CreditedFeedback,
    EpisodeEvent,
    HelpAnswer,
    HelpRequest,
    Message,
    Observation,
    TeacherNotice,
    TeachingStats,
    Utterance,
    parse_key,
    robot_key,
)
from services.runtime import (
    BusConfig,
    BusError,
    ConfigError,
    Input,
    Node,
    Output,
    fields,
)
from services.runtime.limits import Throttle, TokenBucket
from services.teacher.board import ANSWER_WITHIN_S, Board
from services.teacher.session import join_as_teacher
from services.teacher.web import page_url
from services.teacher.web.admission import (
    Admission,
    LoginThrottle,
    Origins,
)
from services.teacher.web.connections import BudgetedSite, connection_budget
from services.teacher.web.gateway import (
    AUDIO_BURST_S,
    MAX_BINARY_BYTES,
    MAX_MESSAGES_PER_S,
    MAX_TEXT_BYTES,
    BrowserError,
    Robots,
    SessionView,
    Teaching,
    feedback_json,
    parse_frame,
    parse_login,
)

LOGIN_WAIT_S = 5.0  # a socket that has not logged in by then is closed
HTTP_IDLE_S = 10.0  # a connection without a whole request for this long is closed
REFUSED = "login refused: wrong user name or password, or not a teacher of this session"
QUEUE_LIMIT = 1000  # messages waiting for one browser (observations aside): beyond, too slow
TICK_S = 0.05  # observations' slots and the "no answer" lines are checked this often
HARD_FRAME_LIMIT = 4 * MAX_BINARY_BYTES  # aiohttp closes the socket above this (1009)


class _Pump:
    """Hands what a node receives (on zenoh's threads, queued by the node) to the loop."""

    def __init__(
        self, node: Node, loop: asyncio.AbstractEventLoop, deliver: Callable[[Any], None]
    ) -> None:
        self.node, self.loop, self.deliver = node, loop, deliver
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._run, name=f"pump-{node.id}", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stopping.is_set():
            item = self.node.poll(0.2)
            if item is None:
                continue
            try:
                self.loop.call_soon_threadsafe(self.deliver, item)
            except RuntimeError:  # the loop is closed: shutting down
                return

    def stop(self) -> None:
        self.stopping.set()
        self.thread.join(timeout=2.0)


class Browser:
    """One socket: its queue to the browser, and once logged in its teacher node."""

    def __init__(self, ws: web.WebSocketResponse, gateway: Gateway, peer: str) -> None:
        self.ws, self.gateway, self.peer = ws, gateway, peer
        self.user: str | None = None  # once it has a teacher's place
        self.queue: deque[str] = deque()
        self.obs: dict[str, str] = {}  # each robot's latest observation waiting
        self.wake = asyncio.Event()
        self.too_slow = False
        self.teaching: Teaching | None = None
        self.node: Node | None = None
        self.outputs: dict[type, Output] = {}
        self.stack = ExitStack()  # the clock exchange and the pump, closed with the node
        # Publishing can block under congestion: one worker per browser keeps the order.
        self.executor = ThreadPoolExecutor(1, thread_name_prefix="publish")

    def send(self, data: dict[str, Any]) -> None:
        if len(self.queue) >= QUEUE_LIMIT:
            self.too_slow = True
        else:
            self.queue.append(json.dumps(data))
        self.wake.set()

    def send_obs(self, robot: str, text: str) -> None:
        self.obs[robot] = text  # the latest wins: an older one not yet sent is dropped
        self.wake.set()

    async def write(self) -> None:
        """Sends what is queued, as the socket takes it."""
        while not self.ws.closed:
            await self.wake.wait()
            self.wake.clear()
            while self.queue or self.obs:
                if self.too_slow:
                    await self.ws.close(code=1008, message=b"too slow: messages piled up")
                    return
                text = self._next()
                try:
                    await self.ws.send_str(text)
                except (ConnectionError, RuntimeError):
                    return

    def _next(self) -> str:
        """Queued messages first, in order; then the robots' latest observations."""
        if self.queue:
            return self.queue.popleft()
        return self.obs.pop(next(iter(self.obs)))

    def publish(self, messages: list[Message]) -> None:
        """On the browser's worker: to the bus, in order."""
        for message in messages:
            try:
                self.outputs[type(message)].put(message)
            except Exception as e:  # the session closing; a bus error
                self.gateway.log.warning("cannot publish", extra=fields(problem=repr(e)))

    def close_node(self) -> None:
        """On the browser's worker, after what it had to publish: leave the bus."""
        self.stack.close()
        if self.node is not None:
            self.node.close()


class Gateway:
    def __init__(
        self,
        bus: BusConfig,
        view: SessionView,
        static: Path,
        address: str,
        tls: ssl.SSLContext | None,
        max_clients: int,
        origins: Origins | None = None,
    ) -> None:
        self.bus, self.view, self.static = bus, view, static
        self.address, self.tls, self.max_clients = address, tls, max_clients
        self.origins = origins or Origins()
        self.admission = Admission(max_clients=max_clients)
        self.throttle = LoginThrottle()
        self.teachers: frozenset[str] | None = None  # who may log in (None: anyone, open)
        self.audio: dict[str, TokenBucket] = {}  # each teacher's audio seconds, all its pages
        self.robots = Robots()
        self.browsers: set[Browser] = set()
        self.node: Node | None = None
        self.logins = 0
        self.loop: asyncio.AbstractEventLoop | None = None
        self._pump: _Pump | None = None
        self._ticker: asyncio.Task | None = None
        self.log = logging.getLogger("voxshape.web")

    # -- the server ---------------------------------------------------------------------
    def app(self) -> web.Application:
        app = web.Application(middlewares=[self._guard], client_max_size=MAX_TEXT_BYTES)
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._socket)
        app.router.add_static("/", self.static, follow_symlinks=False)
        app.on_response_prepare.append(self._headers)
        return app

    async def start(self) -> None:
        """Joins the bus (the gateway's own node) and starts forwarding the robots."""
        self.loop = asyncio.get_running_loop()
        self.node = await asyncio.to_thread(Node, "web", self.bus)
        for topic in ("obs", "episode", "feedback", "teaching", "help", "answer"):
            self.node.input(topic, robot_key(self.node.session_id, "*", topic))
        self._pump = _Pump(self.node, self.loop, self._on_robots)
        self._ticker = asyncio.create_task(self._tick())

    async def stop(self) -> None:
        for browser in list(self.browsers):
            await browser.ws.close(code=1001, message=b"the server is stopping")
        if self._ticker is not None:
            self._ticker.cancel()
        if self._pump is not None:
            self._pump.stop()
        if self.node is not None:
            await asyncio.to_thread(self.node.close)

    async def serve(self, port: int) -> None:
        """Serves until SIGINT or SIGTERM: the page first (a taken port fails at once), then
        the bus."""
        runner = web.AppRunner(self.app(), access_log=None, keepalive_timeout=HTTP_IDLE_S)
        await runner.setup()
        site = BudgetedSite(runner, self.address, port, self.tls, connection_budget())
        try:
            await site.start()
        except OSError as e:
            await runner.cleanup()
            raise ConfigError(
                f"cannot serve the page on {self.address}:{port}: {e.strerror} (another "
                "`voxshape web`? choose another with --port or VOXSHAPE_WEB_PORT)"
            ) from None
        stopping = asyncio.Event()
        for s in (signal.SIGINT, signal.SIGTERM):
            asyncio.get_running_loop().add_signal_handler(s, stopping.set)
        try:
            await self.start()
            self.log.info(
                "serving the page",
                extra=fields(url=page_url(self.address, port, self.tls is not None)),
            )
            if self.view.secured and self.tls is None and self.address not in LOOPBACK:
                self.log.warning(
                    "passwords cross this network in clear: serve HTTPS (--https-cert and "
                    "--https-key) or put an HTTPS proxy in front (docs/web.md)",
                    extra=fields(address=self.address),
                )
            await stopping.wait()
        finally:
            await self.stop()
            await runner.cleanup()

    @web.middleware
    async def _guard(self, request: web.Request, handler: Callable) -> web.StreamResponse:
        if not self.origins.host_allowed(request.host):
            raise web.HTTPForbidden(
                text="this page is not served under that name (--public-origin names it)"
            )
        response = await handler(request)
        # The page loads only its own files and talks only to its own socket.
        response.headers.setdefault(
            "Content-Security-Policy",
            "default-src 'self'; connect-src 'self'; img-src 'self' data:; "
            "style-src 'self' 'unsafe-inline'; frame-ancestors 'none'; base-uri 'none'",
        )
        response.headers.setdefault("X-Content-Type-Options", "nosniff")
        response.headers.setdefault("Referrer-Policy", "no-referrer")
        response.headers.setdefault("Cache-Control", "no-cache")
        return response

    async def _headers(self, request: web.Request, response: web.StreamResponse) -> None:
        """On every response, errors included: no version in Server; HTTPS only, once seen."""
        response.headers["Server"] = "voxshape"
        if self.tls is not None:
            response.headers["Strict-Transport-Security"] = "max-age=31536000"

    async def _index(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(self.static / "index.html")

    # -- the robots, to every browser ---------------------------------------------------
    def _on_robots(self, event: object) -> None:
        if not isinstance(event, Input):
            return
        message = event.message
        if isinstance(message, Observation):
            self._send_obs(self.robots.observation(message, time.time()))
        elif isinstance(message, EpisodeEvent):
            self._broadcast(self.robots.episode(message))
        elif isinstance(message, CreditedFeedback):
            self._broadcast([feedback_json(message)])
        elif isinstance(message, TeachingStats):
            for browser in self.browsers:
                if browser.teaching is not None:
                    browser.send(browser.teaching.stats(message))
            self._broadcast(self.robots.teaching(message))
        elif isinstance(message, HelpRequest):
            owner = parse_key(event.key).owner  # a question on another robot's key: dropped
            self._broadcast(self.robots.question(message, time.time(), owner))
        elif isinstance(message, HelpAnswer):
            self._broadcast(self.robots.answer(message, time.time()))

    def _broadcast(self, items: list[dict[str, Any]]) -> None:
        for item in items:
            for browser in self.browsers:
                browser.send(item)

    def _send_obs(self, items: list[dict[str, Any]]) -> None:
        for item in items:
            text = json.dumps(item)  # once for every browser
            for browser in self.browsers:
                browser.send_obs(item["robot"], text)

    async def _tick(self) -> None:
        while True:
            await asyncio.sleep(TICK_S)
            self._send_obs(self.robots.due(time.time()))
            now = time.monotonic()
            for browser in self.browsers:
                if browser.teaching is not None:
                    for line in browser.teaching.tick(now):
                        browser.send(line)

    # -- one browser --------------------------------------------------------------------
    async def _socket(self, request: web.Request) -> web.StreamResponse:
        scheme = "https" if self.tls is not None else "http"
        peer = request.remote or "-"
        if not self.origins.origin_allowed(request.headers.get("Origin"), request.host, scheme):
            self.log.warning(
                "refused a socket from another origin",
                extra=fields(
                    origin=request.headers.get("Origin", "-"), host=request.host, peer=peer
                ),
            )
            raise web.HTTPForbidden(text="this socket is for the page's own origin")
        refusal = self.admission.open(peer)
        if refusal is not None:
            raise web.HTTPServiceUnavailable(text=refusal)
        ws = web.WebSocketResponse(max_msg_size=HARD_FRAME_LIMIT, heartbeat=30.0)
        browser = Browser(ws, self, peer)
        try:
            await ws.prepare(request)
        except (ConnectionError, RuntimeError):
            self.admission.close(peer, None)
            raise
        writer = asyncio.create_task(browser.write())
        try:
            if await self._login(browser):
                self.browsers.add(browser)
                await self._converse(browser)
        finally:
            self.admission.close(peer, browser.user)
            self.browsers.discard(browser)
            await self._leave(browser)
            writer.cancel()
            if not ws.closed:
                await ws.close()
        return ws

    async def _login(self, browser: Browser) -> bool:
        """The first message: log in, open this teacher's node, welcome. False: refused."""
        ws, peer = browser.ws, browser.peer
        try:
            msg = await asyncio.wait_for(ws.receive(), LOGIN_WAIT_S)
        except TimeoutError:
            await self._refuse(browser, f"log in within {LOGIN_WAIT_S:g} s")
            return False
        if msg.type != WSMsgType.TEXT:
            return False if msg.type in _CLOSING else await self._refuse(browser, "log in first")
        try:
            login = parse_login(parse_frame(msg.data), self.view.secured)
        except BrowserError as e:
            return await self._refuse(browser, str(e))
        keys = (f"address:{peer}", f"user:{login.user}") if self.view.secured else ()
        if (wait := self.throttle.wait(keys, time.monotonic())) > 0:
            self.log.warning(
                "a login came too soon after failed ones",
                extra=fields(user=login.user, peer=peer, wait_s=round(wait, 1)),
            )
            return await self._refuse(browser, f"{REFUSED} (wait a few seconds)")
        if self.teachers is not None and login.teacher not in self.teachers:
            return await self._login_failed(browser, login.teacher, keys, "not a teacher")
        refusal = self.admission.login(peer, login.teacher)
        if refusal is not None:
            return await self._refuse(browser, refusal)
        browser.user = login.teacher
        self.logins += 1
        node_id = f"web-{login.teacher}"[:56] + f"-{self.logins}"
        config = replace(self.bus, node=node_id, user=login.user, password=login.password)
        try:
            await asyncio.to_thread(self._teacher_node, browser, login.teacher, config)
        except (BusError, ConfigError) as e:
            return await self._login_failed(browser, login.teacher, keys, str(e))
        self.throttle.succeeded(keys[:1])
        board = Board(
            answer_within_s=ANSWER_WITHIN_S,
            no_answer_hint=f"no arbiter in session {self.view.session!r} heard it",
        )
        budget = self.audio.setdefault(login.teacher, TokenBucket(1.0, AUDIO_BURST_S))
        browser.teaching = Teaching(login.teacher, self.robots, board, self.view.language, budget)
        browser.send(self.robots.welcome(self.view, login.teacher, time.time()))
        self.log.info(
            "a browser logged in",
            extra=fields(teacher=login.teacher, node=browser.node.id, peer=peer),
        )
        return True

    async def _login_failed(
        self, browser: Browser, user: str, keys: tuple[str, ...], why: str
    ) -> bool:
        """The same refusal for every failure (the log says which); counted for the throttle."""
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
        pump = _Pump(node, self.loop, lambda event: self._on_teacher(browser, event))
        browser.stack.callback(pump.stop)

    def _on_teacher(self, browser: Browser, event: object) -> None:
        if browser.teaching is None or not isinstance(event, Input):
            return
        now = time.monotonic()
        if isinstance(event.message, TeacherNotice):
            for line in browser.teaching.notice(event.message, now):
                browser.send(line)
        elif isinstance(event.message, Utterance):
            browser.teaching.recognized(event.message, now)

    async def _converse(self, browser: Browser) -> None:
        """Every frame after the login, within the limits; an error for each refused."""
        teaching = browser.teaching
        assert teaching is not None and self.loop is not None
        limit, told = TokenBucket(MAX_MESSAGES_PER_S, MAX_MESSAGES_PER_S), Throttle(1.0)
        async for msg in browser.ws:
            now = time.monotonic()
            if msg.type not in (WSMsgType.TEXT, WSMsgType.BINARY):
                continue
            if not limit.take(now):
                if told.due(("too many",), now):
                    text = f"too many messages: at most {MAX_MESSAGES_PER_S} a second"
                    browser.send(_error(text))
                continue
            try:
                if msg.type == WSMsgType.TEXT:
                    outcome = teaching.text(parse_frame(msg.data), time.time(), now)
                else:
                    if len(msg.data) > MAX_BINARY_BYTES:
                        raise BrowserError(f"an audio frame is over {MAX_BINARY_BYTES} bytes")
                    outcome = teaching.audio(msg.data, time.time())
            except BrowserError as e:
                browser.send(_error(str(e)))
                continue
            for reply in outcome.replies:
                browser.send(reply)
            if outcome.messages:
                self.loop.run_in_executor(browser.executor, browser.publish, outcome.messages)

    async def _leave(self, browser: Browser) -> None:
        """Ends its push-to-talk stream, then its node leaves the bus (after what it had to
        publish: same worker)."""
        assert self.loop is not None
        if browser.teaching is not None and browser.teaching.talk is not None:
            ended = browser.teaching.text({"type": "talk", "state": "stop"}, time.time(), 0.0)
            self.loop.run_in_executor(browser.executor, browser.publish, ended.messages)
        await self.loop.run_in_executor(browser.executor, browser.close_node)
        browser.executor.shutdown(wait=False)

    async def _refuse(self, browser: Browser, reason: str) -> bool:
        """Says why, then closes the socket. Always False (not logged in)."""
        with_reason = json.dumps({"type": "refused", "reason": reason})
        try:
            await browser.ws.send_str(with_reason)
            await browser.ws.close(code=1008, message=b"refused")
        except (ConnectionError, RuntimeError):
            pass
        return False


LOOPBACK = ("127.0.0.1", "::1", "localhost")
_CLOSING = (WSMsgType.CLOSE, WSMsgType.CLOSING, WSMsgType.CLOSED, WSMsgType.ERROR)


def _error(text: str) -> dict[str, Any]:
    return {"type": "error", "text": text}

"""The page's server: the aiohttp application, one Browser per socket (browser.py; its login:
login.py), and the PageServer between them and the bus: the robots to every browser, each
browser's frames to its teacher node.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import signal
import ssl
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from aiohttp import WSMsgType, web

from voxshape.deploy.access import compare_with_router
from voxshape.deploy.enforced import ask_access
from voxshape.protocol import (
    CreditedFeedback,
    EpisodeEvent,
    HelpAnswer,
    HelpRequest,
    Learnt,
    Observation,
    TeachingStats,
    parse_key,
)
from voxshape.runtime import BusConfig, ConfigError, Input, Node, fields
from voxshape.runtime.limits import Throttle, TokenBucket
from voxshape.services.web import page_url
from voxshape.services.web.admission import Admission, LoginThrottle, Origins
from voxshape.services.web.browser import Browser, Pump
from voxshape.services.web.connections import Budget, connection_budget, serve_budgeted
from voxshape.services.web.devices import DeviceTokens, device_secret
from voxshape.services.web.frames import (
    MAX_BINARY_BYTES,
    MAX_MESSAGES_PER_S,
    MAX_TEXT_BYTES,
    BrowserError,
    parse_frame,
)
from voxshape.services.web.login import REFUSED as REFUSED
from voxshape.services.web.login import LoginFlow
from voxshape.services.web.page_json import SessionView, feedback_json
from voxshape.services.web.robots import Robots

HTTP_IDLE_S = 10.0  # a connection without a whole request for this long is closed
LOGINS_AT_ONCE = 64  # logins the router checks at once (the throttle lets few wrong ones in)
TICK_S = 0.05  # observations' slots and the "no answer" lines are checked this often
HARD_FRAME_LIMIT = 4 * MAX_BINARY_BYTES  # aiohttp closes the socket above this (1009)
NOT_A_HANDSHAKE = "this is the page's WebSocket: open it with a WebSocket handshake"


class PageServer(LoginFlow):
    """The page's aiohttp server and its bridge to the bus: serves static/, admits sockets,
    sends every page the robots and each browser's frames to its teacher node."""

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
        self.checking = ThreadPoolExecutor(LOGINS_AT_ONCE, thread_name_prefix="login")
        self.devices = DeviceTokens(device_secret(bus.password))
        self.budget = Budget(connection_budget())
        self.teachers: frozenset[str] | None = None  # who may log in (None: anyone, open)
        self.access: tuple[Path, str] | None = None  # their access file and its SHA-256
        self.audio: dict[str, TokenBucket] = {}  # each teacher's audio seconds, all its pages
        self.robots = Robots()
        self.browsers: set[Browser] = set()
        self.node: Node | None = None
        self.logins = 0
        self.loop: asyncio.AbstractEventLoop | None = None
        self._pump: Pump | None = None
        self._ticker: asyncio.Task | None = None
        self.log = logging.getLogger("voxshape.services.web")

    # -- the server ---------------------------------------------------------------------
    def app(self) -> web.Application:
        app = web.Application(middlewares=[self._guard], client_max_size=MAX_TEXT_BYTES)
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._socket)
        app.router.add_post("/ws/device", self._device)
        app.router.add_static("/", self.static, follow_symlinks=False)
        app.on_response_prepare.append(self._headers)
        return app

    async def start(self) -> None:
        """Joins the bus (the gateway's own node) and starts forwarding the robots."""
        self.loop = asyncio.get_running_loop()
        self.node = await asyncio.to_thread(Node, "web", self.bus)
        if self.access is not None:
            await self._same_access_as_the_router(*self.access)
        for topic in ("obs", "episode", "feedback", "teaching", "help", "answer", "learnt"):
            self.node.subscribe(topic)
        self._pump = Pump(self.node, self.loop, self._on_robots)
        self._ticker = asyncio.create_task(self._tick())

    async def _same_access_as_the_router(self, path: Path, digest: str) -> None:
        """ConfigError unless the router enforces the access file the teachers come from."""
        assert self.node is not None
        answers, routers = await asyncio.to_thread(
            ask_access, self.node.zenoh, self.node.session_id
        )
        error, warning = compare_with_router(path, digest, answers, routers)
        if error is not None:
            raise ConfigError(error)
        if warning is not None:
            self.log.warning(warning)

    async def stop(self) -> None:
        for browser in list(self.browsers):
            await browser.ws.close(code=1001, message=b"the server is stopping")
        if self._ticker is not None:
            self._ticker.cancel()
        if self._pump is not None:
            self._pump.stop()
        if self.node is not None:
            await asyncio.to_thread(self.node.close)
        self.checking.shutdown(wait=False)

    async def serve(self, port: int) -> None:
        """Serves until SIGINT or SIGTERM: the page first (a taken port fails at once), then
        the bus."""
        runner = web.AppRunner(self.app(), access_log=None, keepalive_timeout=HTTP_IDLE_S)
        await runner.setup()
        try:
            server = await serve_budgeted(runner, self.address, port, self.tls, self.budget)
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
            server.close()
            await self.stop()
            await runner.cleanup()
            await server.wait_closed()

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
        elif isinstance(message, Learnt):
            self._broadcast(self.robots.has_learnt(message))

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
        ws = web.WebSocketResponse(max_msg_size=HARD_FRAME_LIMIT, heartbeat=30.0)
        if not ws.can_prepare(request).ok:  # a plain GET, a bad key or version: no place
            raise web.HTTPBadRequest(text=NOT_A_HANDSHAKE)
        browser = Browser(ws, peer, request.cookies, request.transport)
        refusal, gone = self.admission.open(browser, browser.address)
        if refusal is not None:
            raise web.HTTPServiceUnavailable(text=refusal)
        if isinstance(gone, Browser):
            gone.evicted.set()
        writer: asyncio.Task | None = None
        try:  # from here on its place is given back on every path
            try:
                await ws.prepare(request)
            except ConnectionError:  # it left during the handshake: nothing more to say
                return web.Response(status=400, text=NOT_A_HANDSHAKE)
            writer = asyncio.create_task(browser.write())
            if await self._login(browser):
                self.browsers.add(browser)
                await self._converse(browser)
        finally:
            self.admission.leave(browser)
            if browser.user is not None:
                self.admission.logout(browser.user)
            self.browsers.discard(browser)
            if writer is not None:
                writer.cancel()
            await self._leave(browser)
            if writer is not None and not ws.closed:  # the handshake was answered
                with contextlib.suppress(ConnectionError):
                    await ws.close()
        return ws

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


LOOPBACK = ("127.0.0.1", "::1", "localhost")


def _error(text: str) -> dict[str, Any]:
    return {"type": "error", "text": text}

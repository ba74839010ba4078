"""One browser's socket on the page's server: its queue to the browser (observations aside:
only each robot's latest waits, so a slow browser never holds up the bus), and once logged
in its teacher node; and the pump that hands what a node receives to the event loop.

Zenoh delivers on its own threads: a pump thread per node hands each message to the event
loop (call_soon_threadsafe).
"""

from __future__ import annotations

import asyncio
import json
import logging
import threading
from collections import deque
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack
from typing import Any

from aiohttp import web

from voxshape.protocol import Message
from voxshape.runtime import Node, Output, fields
from voxshape.services.web.admission import address_key
from voxshape.services.web.gateway import Teaching

QUEUE_LIMIT = 1000  # messages waiting for one browser (observations aside): beyond, too slow
LOG = logging.getLogger("voxshape.services.web")


class Pump:
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

    def __init__(
        self,
        ws: web.WebSocketResponse,
        peer: str,
        cookies: Mapping[str, str],
        transport: asyncio.BaseTransport | None = None,
    ) -> None:
        self.ws, self.peer, self.cookies, self.transport = ws, peer, cookies, transport
        self.address = address_key(peer)  # what the limits count by
        self.evicted = asyncio.Event()  # set when it gives way in a full waiting room
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
                LOG.warning("cannot publish", extra=fields(problem=repr(e)))

    def close_node(self) -> None:
        """On the browser's worker, after what it had to publish: leave the bus."""
        self.stack.close()
        if self.node is not None:
            self.node.close()

"""The page's connections: as many at once as the file-descriptor limit allows (one address,
an IPv6 /64, at most a quarter of them), each closed by aiohttp when idle or half-sent
(keep-alive timeout). When the budget is spent, the oldest connection that is no logged-in
teacher's gives way to the newcomer (so a flood from many addresses churns among itself while
a teacher's page, which logs in within milliseconds, gets in); beyond one address's share, and
when every connection is a teacher's, the newcomer is closed at once. One log line a minute
each, instead of accept() failing with a traceback per connection.

Served through aiohttp's documented low-level interface: the runner's `server` (a
`web.Server`, the protocol factory of `loop.create_server`) behind a protocol of ours that
counts connections; no aiohttp site, no private attribute."""

from __future__ import annotations

import asyncio
import logging
import math
import resource
import ssl
import time
from collections import Counter, OrderedDict
from collections.abc import Callable

from aiohttp import web

from voxshape.runtime import fields
from voxshape.services.web.admission import address_key

FD_RESERVE = 256  # file descriptors kept for the bus, the teachers' nodes and files
BACKLOG = 128  # connections the kernel queues before accept (aiohttp's own default)
PER_ADDRESS = (4, 256)  # one address may hold a quarter of the budget, at most 256


def connection_budget() -> int:
    """Connections served at once: what the file-descriptor limit leaves (its soft limit is
    raised to the hard one first), less FD_RESERVE."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard == resource.RLIM_INFINITY or soft < hard:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
            soft = hard
        except (ValueError, OSError):
            pass
    return max(16, min(soft, 65_536) - FD_RESERVE)


class Budget:
    """Connections open now against the budget, in all and per address; those of logged-in
    teachers (`prove`) never give way. A lab behind one NAT address holds a few per teacher."""

    def __init__(self, budget: int) -> None:
        self.budget, self.refused, self.gave_way = budget, 0, 0
        self.per_address = min(PER_ADDRESS[1], max(8, budget // PER_ADDRESS[0]))
        self.by_address: Counter[str] = Counter()
        self.open: OrderedDict[Budgeted, None] = OrderedDict()  # oldest first
        self.proven: set[Budgeted] = set()
        self.by_transport: dict[asyncio.BaseTransport, Budgeted] = {}
        self.told_at: dict[str, float] = {}
        self.log = logging.getLogger("voxshape.services.web")

    def take(self, conn: Budgeted) -> bool:
        """Whether `conn` is served (after the oldest unproven gave way, if need be)."""
        if self.by_address[conn.address] >= self.per_address:
            return self._tell("refused connections: too many from one address", conn, True)
        if len(self.open) >= self.budget:
            oldest = next((c for c in self.open if c not in self.proven), None)
            if oldest is None:
                return self._tell("refused connections: the budget is spent", conn, True)
            self.release(oldest)
            oldest.give_way()
            self._tell("connections gave way: the budget is spent", oldest, False)
        self.open[conn] = None
        self.by_address[conn.address] += 1
        self.by_transport[conn.transport] = conn
        return True

    def prove(self, transport: asyncio.BaseTransport | None) -> None:
        """The connection of a logged-in teacher: it never gives way."""
        conn = self.by_transport.get(transport) if transport is not None else None
        if conn is not None:
            self.proven.add(conn)

    def release(self, conn: Budgeted) -> None:
        """Its place given back (again is harmless)."""
        if conn not in self.open:
            return
        del self.open[conn]
        self.proven.discard(conn)
        self.by_transport.pop(conn.transport, None)
        self.by_address[conn.address] -= 1
        if self.by_address[conn.address] <= 0:
            del self.by_address[conn.address]

    def _tell(self, why: str, conn: Budgeted, refused: bool) -> bool:
        if refused:
            self.refused += 1
        else:
            self.gave_way += 1
        now = time.monotonic()
        if now - self.told_at.get(why, -math.inf) >= 60.0:
            self.told_at[why] = now
            self.log.warning(
                why,
                extra=fields(
                    budget=self.budget,
                    per_address=self.per_address,
                    refused=self.refused,
                    gave_way=self.gave_way,
                    address=conn.address,
                ),
            )
        return False


class Budgeted(asyncio.Protocol):
    """aiohttp's handler of one connection (`handler()`), unless the budget refuses it: then
    the connection is closed at once rather than let accept() fail for want of descriptors."""

    def __init__(self, budget: Budget, handler: Callable[[], asyncio.Protocol]) -> None:
        self.budget, self.handler = budget, handler
        self.inner: asyncio.Protocol | None = None
        self.transport: asyncio.BaseTransport | None = None
        self.address = "-"

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        peer = transport.get_extra_info("peername")
        self.transport, self.address = transport, address_key(peer[0]) if peer else "-"
        if not self.budget.take(self):
            transport.abort()
            return
        self.inner = self.handler()
        self.inner.connection_made(transport)

    def give_way(self) -> None:
        assert self.transport is not None
        self.transport.abort()  # aiohttp hears of it in connection_lost, as of any reset

    def connection_lost(self, exc: Exception | None) -> None:
        if self.inner is not None:
            self.budget.release(self)
            self.inner.connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self.inner is not None:
            self.inner.data_received(data)

    def eof_received(self) -> bool | None:
        return self.inner.eof_received() if self.inner is not None else None

    def pause_writing(self) -> None:
        if self.inner is not None:
            self.inner.pause_writing()

    def resume_writing(self) -> None:
        if self.inner is not None:
            self.inner.resume_writing()


async def serve_budgeted(
    runner: web.AppRunner, host: str, port: int, tls: ssl.SSLContext | None, budget: Budget
) -> asyncio.Server:
    """Listens on host:port for a runner already set up; close the server returned before
    `runner.cleanup()`. OSError if the address cannot be bound."""
    handler = runner.server
    if handler is None:
        raise RuntimeError("serve_budgeted needs `await runner.setup()` first")
    return await asyncio.get_running_loop().create_server(
        lambda: Budgeted(budget, handler),
        host,
        port,
        ssl=tls,
        backlog=BACKLOG,
        reuse_address=True,
    )

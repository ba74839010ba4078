"""The page's connections: as many at once as the file-descriptor limit allows, each closed
by aiohttp when idle or half-sent (keep-alive timeout), the rest closed at once with one log
line a minute, instead of accept() failing with a traceback per connection."""

from __future__ import annotations

import asyncio
import logging
import math
import resource
import ssl
import time

from aiohttp import web

from services.runtime import fields

FD_RESERVE = 256  # file descriptors kept for the bus, the teachers' nodes and files


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


class _Connection(asyncio.Protocol):
    """aiohttp's handler of one connection, unless the budget is spent: then it is closed at
    once (one log line a minute) rather than let accept() fail for want of descriptors."""

    def __init__(self, site: BudgetedSite) -> None:
        self.site = site
        self.inner: asyncio.Protocol | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        site = self.site
        if site.open >= site.budget:
            site.refused += 1
            now = time.monotonic()
            if now - site.told_at >= 60.0:
                site.told_at = now
                site.log.warning(
                    "refused connections: the budget is spent",
                    extra=fields(budget=site.budget, refused=site.refused),
                )
            transport.abort()
            return
        site.open += 1
        self.inner = site.runner.server()
        self.inner.connection_made(transport)

    def connection_lost(self, exc: Exception | None) -> None:
        if self.inner is not None:
            self.site.open -= 1
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


class BudgetedSite(web.TCPSite):
    """aiohttp's TCP site, each connection through `_Connection`'s budget."""

    def __init__(
        self,
        runner: web.AppRunner,
        host: str,
        port: int,
        tls: ssl.SSLContext | None,
        budget: int,
    ) -> None:
        super().__init__(runner, host, port, ssl_context=tls)
        self.runner, self.budget, self.open, self.refused = runner, budget, 0, 0
        self.told_at = -math.inf
        self.log = logging.getLogger("voxshape.web")

    async def start(self) -> None:
        await web.BaseSite.start(self)
        self._server = await asyncio.get_running_loop().create_server(
            lambda: _Connection(self),
            self._host,
            self._port,
            ssl=self._ssl_context,
            backlog=self._backlog,
            reuse_address=self._reuse_address,
        )

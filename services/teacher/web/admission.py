"""Who may open the page's socket and log in, pure (no aiohttp): the names the page is served
under, how many sockets wait to log in and how many teachers are on, and how fast a password
may be guessed. The limits and their defaults are listed in docs/web.md#security.
"""

from __future__ import annotations

import ipaddress
import math
from collections import Counter, OrderedDict
from dataclasses import dataclass, field
from urllib.parse import urlsplit

LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1", "[::1]")


class AdmissionError(ValueError):
    """A configuration of the page that cannot be served (a malformed --public-origin)."""


def _hostname(netloc: str) -> str:
    """`host` of `host:port` (IPv6 in brackets kept whole)."""
    if netloc.startswith("["):
        return netloc[: netloc.find("]") + 1]
    return netloc.rsplit(":", 1)[0] if netloc.count(":") == 1 else netloc


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name.strip("[]"))
        return True
    except ValueError:
        return False


def public_origin(text: str) -> str:
    """`scheme://host[:port]` of --public-origin, normalised; AdmissionError if it is not."""
    parts = urlsplit(text.strip().lower())
    if parts.scheme not in ("http", "https") or not parts.netloc or parts.path not in ("", "/"):
        raise AdmissionError(
            f"--public-origin {text!r} is not like https://lab.example:8443 (scheme, host and "
            "port the teachers' browsers open, nothing after)"
        )
    return f"{parts.scheme}://{parts.netloc}"


@dataclass(frozen=True)
class Origins:
    """The names the page is served under. A request's Host must be one of them and a
    socket's Origin the page's own, whatever address the gateway binds: a name an attacker
    controls, made to resolve here (DNS rebinding), is refused.

    Allowed Hosts: loopback names, IP literals (they cannot be rebound), this machine's own
    names, and the --public-origin's host; a socket's Origin: the public origin, or the
    scheme and Host of its own request."""

    public: str | None = None  # e.g. https://lab.example:8443
    own_names: frozenset[str] = frozenset()  # this machine's host names, lower case

    def host_allowed(self, host: str | None) -> bool:
        if not host:
            return False
        host = host.lower()
        name = _hostname(host)
        if name in LOOPBACK_NAMES or _is_ip(name) or name in self.own_names:
            return True
        return self.public is not None and host == urlsplit(self.public).netloc

    def origin_allowed(self, origin: str | None, host: str | None, scheme: str) -> bool:
        if not origin or not self.host_allowed(host):
            return False
        origin = origin.lower().rstrip("/")
        assert host is not None
        return origin == self.public or origin == f"{scheme}://{host.lower()}"


@dataclass
class Admission:
    """Sockets that have not logged in yet wait in their own limited room (per address too),
    so they can never keep a teacher out; the teachers' places (`max_clients`, at most
    `per_user` pages for one user) are taken at login. Each method returns why a socket is
    refused, or None."""

    max_clients: int = 20
    per_user: int = 3
    max_waiting: int = 64
    waiting_per_address: int = 8
    waiting: Counter[str] = field(default_factory=Counter)  # by address
    teachers: Counter[str] = field(default_factory=Counter)  # pages by user

    def open(self, address: str) -> str | None:
        if sum(self.waiting.values()) >= self.max_waiting:
            return f"{self.max_waiting} pages are logging in already: try again in a few seconds"
        if self.waiting[address] >= self.waiting_per_address:
            return f"{self.waiting_per_address} pages of this address are logging in already"
        self.waiting[address] += 1
        return None

    def login(self, address: str, user: str) -> str | None:
        """Moves a waiting socket to a teacher's place, if one is free."""
        if self.teachers[user] >= self.per_user:
            return f"{user} has {self.per_user} pages open already: close one"
        if sum(self.teachers.values()) >= self.max_clients:
            return f"{self.max_clients} pages are open already (--max-clients)"
        self._unwait(address)
        self.teachers[user] += 1
        return None

    def close(self, address: str, user: str | None) -> None:
        """A socket ended: logged in as `user` (its place freed), or still waiting."""
        if user is None:
            self._unwait(address)
            return
        self.teachers[user] -= 1
        if self.teachers[user] <= 0:
            del self.teachers[user]

    def _unwait(self, address: str) -> None:
        self.waiting[address] -= 1
        if self.waiting[address] <= 0:
            del self.waiting[address]


class LoginThrottle:
    """Failed logins, per address and per user: after `free` failures each next attempt must
    wait twice as long as the last (1 s, 2 s, 4 s... at most `longest`); forgotten after
    `forget_s` without a failure. Bounded: the oldest keys go first beyond `max_keys`."""

    def __init__(
        self,
        free: int = 3,
        longest: float = 60.0,
        forget_s: float = 900.0,
        max_keys: int = 10_000,
    ) -> None:
        self.free, self.longest, self.forget_s, self.max_keys = free, longest, forget_s, max_keys
        self._failures: OrderedDict[str, tuple[int, float]] = OrderedDict()  # count, last

    def wait(self, keys: tuple[str, ...], now: float) -> float:
        """Seconds before these keys may try again (0: now)."""
        return max((self._wait(key, now) for key in keys), default=0.0)

    def _wait(self, key: str, now: float) -> float:
        count, last = self._failures.get(key, (0, -math.inf))
        if now - last >= self.forget_s:
            return 0.0
        if count < self.free:
            return 0.0
        delay = min(self.longest, 2.0 ** (count - self.free))
        return max(0.0, last + delay - now)

    def failed(self, keys: tuple[str, ...], now: float) -> None:
        for key in keys:
            count, last = self._failures.pop(key, (0, -math.inf))
            count = 0 if now - last >= self.forget_s else count
            self._failures[key] = (count + 1, now)
        while len(self._failures) > self.max_keys:
            self._failures.popitem(last=False)

    def succeeded(self, keys: tuple[str, ...]) -> None:
        for key in keys:
            self._failures.pop(key, None)

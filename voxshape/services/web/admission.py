"""Who may open the page's socket and log in, pure (no aiohttp): the names the page is served
under, how many sockets wait to log in and how many teachers are on, and how fast a password
may be guessed (the throttle's keys, so that no stranger can lock a teacher out). The limits
and their defaults are listed in docs/web.md#security.
"""

from __future__ import annotations

import ipaddress
import math
from collections import Counter, OrderedDict
from collections.abc import Hashable, Mapping
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


def address_key(peer: str) -> str:
    """The address limits count by: an IPv4 address, or an IPv6 address's /64 (one site's
    network: a host there may take any address of it)."""
    try:
        ip = ipaddress.ip_address(peer)
    except ValueError:
        return peer
    if ip.version == 6 and ip.ipv4_mapped is not None:
        return str(ip.ipv4_mapped)
    return str(ipaddress.ip_network(f"{ip}/64", strict=False)) if ip.version == 6 else str(ip)


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
    """Sockets that have not sent their first frame yet wait in a limited room of their own
    (`waiting_per_address` of one address, `max_waiting` in all), so they never take a
    teacher's place; when the room is full the socket that waited longest gives way to the
    newcomer (a teacher's page sends its login at once: strangers' idle sockets go first).
    The teachers' places (`max_clients`, at most `per_user` pages for one user) are taken
    once the router has let a login in."""

    max_clients: int = 20
    per_user: int = 3
    max_waiting: int = 64
    waiting_per_address: int = 8
    waiting: OrderedDict[Hashable, str] = field(default_factory=OrderedDict)  # oldest first
    by_address: Counter[str] = field(default_factory=Counter)
    teachers: Counter[str] = field(default_factory=Counter)  # pages by user

    def open(self, socket: Hashable, address: str) -> tuple[str | None, Hashable | None]:
        """A socket enters the room: (why it is refused, None), or (None, the socket that
        gave way to it, if the room was full)."""
        if self.by_address[address] >= self.waiting_per_address:
            return f"{self.waiting_per_address} pages of this address are logging in already", None
        gone = None
        if len(self.waiting) >= self.max_waiting:
            gone = next(iter(self.waiting))
            self.leave(gone)
        self.waiting[socket] = address
        self.by_address[address] += 1
        return None, gone

    def leave(self, socket: Hashable) -> None:
        """Out of the room (its first frame came, or it closed); again is harmless."""
        address = self.waiting.pop(socket, None)
        if address is not None:
            self.by_address[address] -= 1
            if self.by_address[address] <= 0:
                del self.by_address[address]

    def login(self, user: str) -> str | None:
        """A teacher's place for a login the router let in, if one is free."""
        if self.teachers[user] >= self.per_user:
            return f"{user} has {self.per_user} pages open already: close one"
        if sum(self.teachers.values()) >= self.max_clients:
            return f"{self.max_clients} pages are open already (--max-clients)"
        self.teachers[user] += 1
        return None

    def logout(self, user: str) -> None:
        self.teachers[user] -= 1
        if self.teachers[user] <= 0:
            del self.teachers[user]


# Failures each key of the throttle lets through before a login must wait (docs/web.md):
FREE_FAILURES: Mapping[str, int] = {
    "user-address": 3,  # one user from one address: a guesser at one machine
    "device": 3,  # one browser holding the user's device cookie: the same, for that browser
    "address": 10,  # any user from one address: one machine trying many users
    "user": 10,  # one user from browsers without its device cookie: guessing from many
}


def login_keys(user: str, address: str, teacher: bool, device: str | None) -> tuple[str, ...]:
    """The throttle's keys of a login as `user` from `address` (address_key). A browser with
    a valid device cookie of that user (`device`: its nonce) counts under its own key only,
    so strangers failing as the user, from anywhere, never hold it up; a name that is no
    teacher only under the address (no key per made-up name)."""
    if not teacher:
        return (f"address:{address}",)
    if device is not None:
        return (f"device:{user}:{device}",)
    return (f"user-address:{user}@{address}", f"address:{address}", f"user:{user}")


class LoginThrottle:
    """Failed logins per key ("kind:value", kinds of FREE_FAILURES): after a key's free
    failures, each next attempt must wait twice as long as the last (1 s, 2 s, 4 s... at
    most `longest`, counted from the last failure); forgotten after `forget_s` without a
    failure. An attempt is counted as failed when it is let through (`attempt`), before the
    router is asked, so guesses sent at once are counted at once; a success clears its keys.
    Bounded: the oldest keys go first beyond `max_keys`."""

    def __init__(
        self,
        free: Mapping[str, int] = FREE_FAILURES,
        longest: float = 60.0,
        forget_s: float = 900.0,
        max_keys: int = 100_000,
    ) -> None:
        self.free, self.longest, self.forget_s, self.max_keys = free, longest, forget_s, max_keys
        self._failures: OrderedDict[str, tuple[int, float]] = OrderedDict()  # count, last

    def wait(self, keys: tuple[str, ...], now: float) -> float:
        """Seconds before these keys may try again (0: now)."""
        return max((self._wait(key, now) for key in keys), default=0.0)

    def _wait(self, key: str, now: float) -> float:
        count, last = self._failures.get(key, (0, -math.inf))
        free = self.free[key.split(":", 1)[0]]
        if now - last >= self.forget_s or count < free:
            return 0.0
        delay = min(self.longest, 2.0 ** (count - free))
        return max(0.0, last + delay - now)

    def attempt(self, keys: tuple[str, ...], now: float) -> float:
        """0 and the attempt counted as a failure until it succeeds, or the seconds to wait
        (nothing counted: waiting costs the keys nothing more)."""
        wait = self.wait(keys, now)
        if wait > 0:
            return wait
        for key in keys:
            count, last = self._failures.pop(key, (0, -math.inf))
            count = 0 if now - last >= self.forget_s else count
            self._failures[key] = (count + 1, now)
        while len(self._failures) > self.max_keys:
            self._failures.popitem(last=False)
        return 0.0

    def failed(self, keys: tuple[str, ...], now: float) -> None:
        """An attempt refused (already counted): the wait runs from now, its refusal."""
        for key in keys:
            if key in self._failures:
                self._failures[key] = (self._failures[key][0], now)

    def succeeded(self, keys: tuple[str, ...]) -> None:
        for key in keys:
            self._failures.pop(key, None)

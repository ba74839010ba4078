"""Rate limits every service may use: a token bucket, and a throttle of one event per key
per interval. Pure: times are passed in, so tests and the experiments drive them."""

from __future__ import annotations

import math
from collections import OrderedDict


class TokenBucket:
    """`rate` tokens a second, at most `burst`; `take` spends `cost` of them. `scale`: clock
    seconds per second of the rate (a teacher who lives in robot time, at the robot's pace).
    A clock set back refills nothing; the bucket starts full."""

    def __init__(self, rate: float, burst: float, now: float = -math.inf) -> None:
        self.rate, self.burst = rate, burst
        self.tokens = burst
        self.updated = now

    def take(self, now: float, cost: float = 1.0, scale: float = 1.0) -> bool:
        elapsed = max(0.0, now - self.updated) / max(scale, 1e-9)
        self.tokens = min(self.burst, self.tokens + elapsed * self.rate)
        self.updated = max(self.updated, now)  # an earlier time refills once only
        if self.tokens >= cost:
            self.tokens -= cost
            return True
        return False


class Throttle:
    """At most one event per key per `every` seconds (the `capacity` latest keys kept)."""

    def __init__(self, every: float, capacity: int = 1024) -> None:
        self.every = every
        self.capacity = capacity
        self._last: OrderedDict[tuple[str, ...], float] = OrderedDict()

    def due(self, key: tuple[str, ...], now: float) -> bool:
        last = self._last.get(key)
        if last is not None and 0 <= now - last < self.every:
            return False
        self._last[key] = now
        self._last.move_to_end(key)
        if len(self._last) > self.capacity:
            self._last.popitem(last=False)
        return True

"""What keeps bad traffic out, bounded in memory: duplicates (same message id), floods (a
token bucket per teacher), and notices that would themselves flood (one per teacher and kind
per interval)."""

from __future__ import annotations

from collections import OrderedDict


class RecentIds:
    """The latest `capacity` message ids (least recently seen forgotten first)."""

    def __init__(self, capacity: int = 4096) -> None:
        self.capacity = capacity
        self._ids: OrderedDict[str, None] = OrderedDict()

    def seen(self, message_id: str) -> bool:
        """True if `message_id` was seen before; remembers it either way."""
        if message_id in self._ids:
            self._ids.move_to_end(message_id)
            return True
        self._ids[message_id] = None
        if len(self._ids) > self.capacity:
            self._ids.popitem(last=False)
        return False


class TokenBucket:
    """`rate` tokens per second up to `burst`; each utterance takes one. `scale`: clock seconds
    per second of the rate (a teacher who lives in robot time, at the robot's pace)."""

    def __init__(self, rate: float, burst: float, now: float) -> None:
        self.rate, self.burst = rate, burst
        self.tokens = burst
        self.updated = now

    def take(self, now: float, scale: float = 1.0) -> bool:
        elapsed = max(0.0, now - self.updated) / max(scale, 1e-9)  # set back: refills nothing
        self.tokens = min(self.burst, self.tokens + elapsed * self.rate)
        self.updated = max(self.updated, now)  # nor later: an earlier time refills once
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False


class RateLimits:
    """A token bucket per teacher."""

    def __init__(self, rate: float, burst: float) -> None:
        self.rate, self.burst = rate, burst
        self._buckets: dict[str, TokenBucket] = {}

    def allow(self, teacher: str, now: float, scale: float = 1.0) -> bool:
        bucket = self._buckets.get(teacher)
        if bucket is None:
            bucket = self._buckets[teacher] = TokenBucket(self.rate, self.burst, now)
        return bucket.take(now, scale)

    def forget(self, teacher: str) -> None:
        self._buckets.pop(teacher, None)


class Throttle:
    """At most one event per key per `every` seconds."""

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

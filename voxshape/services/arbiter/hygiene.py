"""What keeps bad traffic out, bounded in memory: duplicates (same message id), floods (a
token bucket per teacher), and notices that would themselves flood (one per teacher and kind
per interval)."""

from __future__ import annotations

from collections import OrderedDict

from voxshape.runtime.limits import TokenBucket


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


class RateLimits:
    """A token bucket per teacher."""

    def __init__(self, rate: float, burst: float) -> None:
        self.rate, self.burst = rate, burst
        self._buckets: dict[str, TokenBucket] = {}

    def allow(self, teacher: str, now: float, scale: float = 1.0) -> bool:
        bucket = self._buckets.get(teacher)
        if bucket is None:
            bucket = self._buckets[teacher] = TokenBucket(self.rate, self.burst, now)
        return bucket.take(now, scale=scale)

    def forget(self, teacher: str) -> None:
        self._buckets.pop(teacher, None)

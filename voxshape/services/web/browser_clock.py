"""A browser's clock against the gateway's: offsets from its probes (the gateway's one-way
bound, or the round trips the browser measured itself), and browser times as gateway seconds
when they can be believed."""

from __future__ import annotations

from typing import Any

from voxshape.services.web.frames import BrowserError, finite_number
from voxshape.services.web.page_json import now_ms

ONSET_TRUST_S = 10.0  # a browser time converted further than this from now is not believed
TRUSTED_RTT_MS = 1000.0  # a reported clock offset may sit this far below the one-way bound


class BrowserClock:
    """A browser's clock against the gateway's. Each probe's t0 (browser ms) and arrival t1
    (gateway ms) bound the offset from above: t1 - t0 = offset + the trip, so the smallest
    such difference is the best estimate the gateway can make alone. A browser that measured
    round trips itself reports its best (offset_ms, rtt_ms) in its probes, as a teacher's
    ClockProbe does on the bus; the lowest round trip reported wins over the one-way bound."""

    def __init__(self) -> None:
        self.one_way: float | None = None  # min(t1 - t0), ms
        self.reported: tuple[float, float] | None = None  # (offset_ms, rtt_ms)

    @property
    def offset_ms(self) -> float | None:
        """Gateway clock minus browser clock (ms); None before any probe."""
        return self.reported[0] if self.reported else self.one_way

    @property
    def rtt_ms(self) -> float | None:
        return self.reported[1] if self.reported else None

    def probe(self, data: dict[str, Any], now_s: float) -> dict[str, Any]:
        t0, t1 = finite_number(data, "t0"), now_ms(now_s)
        if self.one_way is None or t1 - t0 < self.one_way:
            self.one_way = t1 - t0
        offset, rtt = data.get("offset_ms"), data.get("rtt_ms")
        if offset is not None or rtt is not None:
            offset, rtt = finite_number(data, "offset_ms"), finite_number(data, "rtt_ms")
            if not 0 <= rtt <= 60_000:
                raise BrowserError(f"clock: rtt_ms {rtt:g} is not within 0-60000")
            # t1 - t0 = offset + the way here, which is within [0, rtt]: a reported offset
            # outside what the gateway's own bound allows is moved to its edge
            lowest = self.one_way - min(rtt, TRUSTED_RTT_MS)
            offset = min(self.one_way, max(lowest, offset))
            if self.reported is None or rtt <= self.reported[1]:
                self.reported = (offset, rtt)
        return {
            "type": "clock",
            "t0": t0,
            "t1": t1,
            "offset_ms": self.offset_ms,
            "rtt_ms": self.rtt_ms,
        }

    def to_gateway(self, browser_ms: float, now_s: float) -> float:
        """A browser time as gateway seconds; the arrival time when it cannot be believed
        (no probe yet, or further than ONSET_TRUST_S from now)."""
        if self.offset_ms is None:
            return now_s
        at = (browser_ms + self.offset_ms) / 1000.0
        return at if abs(at - now_s) <= ONSET_TRUST_S else now_s

"""A node's flows, typed: the events its loop yields (Input, Presence, Tick) and the Output it
sends on; and how zenoh's advanced publisher and subscriber make a kept output and a
recovering input, so that what a restart made a subscriber miss still reaches it."""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, replace

import zenoh
from zenoh.ext import (
    AdvancedPublisher,
    AdvancedSubscriber,
    CacheConfig,
    HistoryConfig,
    MissDetectionConfig,
    RecoveryConfig,
    RepliesConfig,
    declare_advanced_publisher,
    declare_advanced_subscriber,
)

from voxshape.protocol import Message, encode

HEARTBEAT_S = 0.5  # a kept output announces its latest sequence number this often
HISTORY_SUFFIX = "@adv/**"  # under a kept output's key: where zenoh answers for what it keeps


@dataclass(frozen=True)
class Input:
    """A decoded message that arrived on the input called `name`."""

    name: str
    key: str
    message: Message


@dataclass(frozen=True)
class Presence:
    """A node appeared (`alive`) or left the session."""

    role: str
    node: str
    alive: bool


@dataclass(frozen=True)
class Tick:
    """The periodic timer of `events(tick=...)`."""

    time: float


Event = Input | Presence | Tick


class Output:
    """A declared publisher of one key; `put` stamps (as sent by node `sender`), validates,
    encodes and sends, and counts it in the node's `counters`."""

    def __init__(
        self,
        sender: str,
        counters: Counter[str],
        name: str,
        key: str,
        publisher: zenoh.Publisher,
        kept: bool = False,
    ) -> None:
        self.name, self.key, self.kept = name, key, kept
        self._sender, self._counters, self._publisher = sender, counters, publisher

    def put(self, message: Message) -> None:
        stamped = replace(message, sender=self._sender, sent_at=time.time())
        self._publisher.put(encode(stamped))
        self._counters[f"sent.{self.name}"] += 1

    def has_subscribers(self) -> bool:
        """Whether a subscriber matches this key now, as far as zenoh knows (through a
        router: once the router has told this session of the subscription)."""
        if self.kept:
            raise TypeError(f"output {self.name!r} is kept: zenoh cannot tell its subscribers")
        return self._publisher.matching_status.matching


def kept_publisher(
    session: zenoh.Session, key: str, congestion: zenoh.CongestionControl, keep: int
) -> AdvancedPublisher:
    """A publisher that keeps its last `keep` messages for recovering inputs, and announces
    its sequence numbers so that they notice what they missed. The heartbeat is periodic:
    zenoh sends a sporadic one with BLOCK, which a stopped subscriber's full queue turns into
    a stall of every publisher behind the router (docs/decisions.md, 2026-11-28); the cache's
    replies go with the output's own congestion control, for the same reason."""
    return declare_advanced_publisher(
        session,
        key,
        congestion_control=congestion,
        express=True,
        cache=CacheConfig(
            max_samples=keep, replies_config=RepliesConfig(congestion_control=congestion)
        ),
        sample_miss_detection=MissDetectionConfig(heartbeat=HEARTBEAT_S, sporadic_heartbeat=None),
        publisher_detection=True,
    )


def recovering_subscriber(
    session: zenoh.Session,
    key: str,
    handler: Callable[[zenoh.Sample], None] | zenoh.handlers.FifoChannel,
    recover: float,
) -> AdvancedSubscriber:
    """A subscriber that fetches from kept outputs what it missed, and on joining what they
    published in the last `recover` seconds (math.inf: whatever they keep; 0: nothing)."""
    history = None
    if recover > 0:
        max_age = None if math.isinf(recover) else recover
        history = HistoryConfig(detect_late_publishers=True, max_age=max_age)
    return declare_advanced_subscriber(
        session,
        key,
        handler,
        history=history,
        recovery=RecoveryConfig(periodic_queries=None, heartbeat=True),
        subscriber_detection=recover > 0,
    )


def query_history(
    session: zenoh.Session,
    key: str,
    on_sample: Callable[[zenoh.Sample], None],
    seconds: float,
) -> None:
    """Asks the kept outputs on `key` for what they published in the last `seconds`; the
    replies go to `on_sample` as they come."""

    def on_reply(reply: zenoh.Reply) -> None:
        if reply.ok is not None and zenoh.KeyExpr(key).intersects(reply.ok.key_expr):
            on_sample(reply.ok)

    since = "" if math.isinf(seconds) else f"?_time=[now(-{seconds:g}s)..]"
    session.get(
        f"{key}/{HISTORY_SUFFIX}{since}",
        on_reply,
        consolidation=zenoh.ConsolidationMode.NONE,
        accept_replies=zenoh.ReplyKeyExpr.ANY,
    )


def kept_now(session: zenoh.Session, key: str, timeout: float) -> list[zenoh.Sample]:
    """What the kept outputs on `key` hold now, asked and waited for (at most `timeout`
    seconds): for a node that needs it before going on."""
    replies = session.get(
        f"{key}/{HISTORY_SUFFIX}",
        timeout=timeout,
        consolidation=zenoh.ConsolidationMode.NONE,
        accept_replies=zenoh.ReplyKeyExpr.ANY,
    )
    wanted = zenoh.KeyExpr(key)
    return [r.ok for r in replies if r.ok is not None and wanted.intersects(r.ok.key_expr)]

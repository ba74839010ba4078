"""A service's handle on the bus: a small loop over typed events.

    with Node("sim", bus_config("sim", args)) as node:
        obs = node.output("obs", robot_key(node.session_id, "r1", "obs"))
        node.input("action", robot_key(node.session_id, "r1", "action"))
        for event in node.events(tick=0.1):
            match event:
                case Input(name="action", message=action): ...
                case Tick(): obs.put(...)

Inputs are decoded strictly with the type their key carries; a malformed message is counted
and logged, never delivered and never fatal. What must survive a restart of its subscriber or
of the router goes out on a kept output (zenoh's advanced publisher, which keeps its last N
messages) and comes in on a recovering input (an advanced subscriber that fetches what it
missed, and on joining the last S seconds), as the role's flows in protocol/dataflow.py say;
the messages' ids tell a copy from a new one. The node holds a liveliness token at
`voxshape/<session>/presence/<role>/<node>` while it lives, and `events()` ends on
SIGINT/SIGTERM, after which leaving the `with` block closes everything cleanly.
"""

from __future__ import annotations

import logging
import os
import queue
import signal
import socket
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace

import zenoh
from zenoh.ext import (
    CacheConfig,
    HistoryConfig,
    Miss,
    MissDetectionConfig,
    RecoveryConfig,
    declare_advanced_publisher,
    declare_advanced_subscriber,
)

from protocol import Message, ProtocolError, decode, encode, parse_key, presence_key
from protocol.dataflow import Direction, check, flow_of
from services.runtime.config import BusConfig, tcp_address
from services.runtime.logs import fields, worth_logging

SIGNAL_CHECK_S = 0.1  # events() notices SIGINT/SIGTERM within this
HEARTBEAT_S = 0.5  # a kept output announces its latest sequence number this often (if new)
HISTORY_SUFFIX = "@adv/**"  # under a kept output's key: where zenoh answers for what it keeps


class BusError(RuntimeError):
    """The bus cannot be joined; the message says why and what to do."""


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
_STOP = object()


def default_node_id(role: str) -> str:
    host = "".join(c if c.isalnum() or c in "_-" else "-" for c in socket.gethostname())
    return f"{role}-{host[:40]}-{os.getpid()}"


LOGIN_WAIT_S = 1.2  # a router that answers lets a good login in within milliseconds


def open_session(config: BusConfig) -> zenoh.Session:
    """Opens a zenoh session, translating zenoh's errors into what a user should do. A user
    whose router answers is either let in within milliseconds or refused: refused, it is told
    so at once, not after the whole connect timeout."""
    answering = config.mode != "router" and _router_answers(config.connect)
    if config.user is not None and answering:
        quick = replace(config, connect_timeout=min(config.connect_timeout, LOGIN_WAIT_S))
        try:
            return zenoh.open(quick.zenoh_config())
        except zenoh.ZError as e:
            if "Unable to connect" not in str(e):
                raise _bus_error(config, str(e)) from None
            tls = any(e.startswith("tls/") for e in config.connect)
            raise BusError(
                f"the router at {', '.join(config.connect)} refused user {config.user!r}: a "
                "wrong password or a user it does not know"
                + (
                    ", or a certificate it does not accept (--tls-root-ca; mutual TLS: "
                    "--tls-cert/--tls-key)"
                    if tls
                    else " (or this port is its TLS endpoint: connect with tls/)"
                )
                + ". Check the password (VOXSHAPE_PASSWORD or VOXSHAPE_PASSWORD_FILE; `voxshape "
                "certs` wrote it in the session's credentials file) with the session's admin; "
                "RUST_LOG=debug shows zenoh's own log of the refusal."
            ) from None
    try:
        return zenoh.open(config.zenoh_config())
    except zenoh.ZError as e:
        raise _bus_error(config, str(e), answering) from None


def _bus_error(config: BusConfig, text: str, answering: bool = False) -> BusError:
    if "Unable to connect" in text:
        if answering:
            return BusError(
                f"the router at {', '.join(config.connect)} answers but refused this session "
                f"within {config.connect_timeout:g} s: a secured router needs a user and its "
                "password (--user, VOXSHAPE_PASSWORD) and, on tls/, --tls-root-ca"
            )
        return BusError(
            f"cannot reach {', '.join(config.connect)} within {config.connect_timeout:g} s. "
            "Is the session's router running? Locally, `voxshape up` starts one; remotely, "
            "check --connect/VOXSHAPE_CONNECT and the credentials."
        )
    if "listen" in text.lower() or "address" in text.lower():
        return BusError(
            f"cannot listen on {', '.join(config.listen)}: {text.split(' at ')[0]}. "
            "Is another router already using it? Choose another with --listen."
        )
    return BusError(f"zenoh refused to open the session: {text.split(' at ')[0]}")


def _router_answers(endpoints: tuple[str, ...], timeout: float = 0.5) -> bool:
    """Whether something accepts TCP connections at one of the tcp/ or tls/ endpoints."""
    for address in filter(None, map(tcp_address, endpoints)):
        try:
            with socket.create_connection(address, timeout=timeout):
                return True
        except OSError:
            continue
    return False


class Output:
    """A declared publisher of one key; `put` stamps, validates, encodes and sends."""

    def __init__(
        self, node: Node, name: str, key: str, publisher: zenoh.Publisher, kept: bool = False
    ) -> None:
        self.name, self.key, self.kept = name, key, kept
        self._node, self._publisher = node, publisher

    def put(self, message: Message) -> None:
        stamped = replace(message, sender=self._node.id, sent_at=time.time())
        self._publisher.put(encode(stamped))
        self._node.counters[f"sent.{self.name}"] += 1

    def has_subscribers(self) -> bool:
        """Whether a subscriber matches this key now, as far as zenoh knows (through a
        router: once the router has told this session of the subscription)."""
        if self.kept:
            raise TypeError(f"output {self.name!r} is kept: zenoh cannot tell its subscribers")
        return self._publisher.matching_status.matching


class Node:
    def __init__(self, role: str, config: BusConfig, *, quiet: bool = False) -> None:
        """`quiet` (for tools) keeps this node's routine logs out unless debugging."""
        self.role = role
        self.config = config
        self.session_id = config.session
        self.id = config.node or default_node_id(role)
        self.log = logging.getLogger(f"voxshape.{role}")
        if quiet and not self.log.isEnabledFor(logging.DEBUG):
            self.log.setLevel(logging.WARNING)
        self.counters: Counter[str] = Counter()
        # Not queue.SimpleQueue: on CPython 3.11 its get(timeout=t) can wait for the next
        # put instead of t (when the deadline passes inside it, the time left turns negative,
        # which its C code takes as "forever"); a simulator waiting 5 ms for its next tick
        # then sleeps until an action comes, and none comes (tests/test_bus.py).
        self._queue: queue.Queue = queue.Queue()
        self._stopping = threading.Event()
        self._signalled = False  # set by SIGINT/SIGTERM: a plain flag, no lock to take
        self._declared: list = []
        self._recovering: dict[str, tuple[str, Callable[[zenoh.Sample], None], float]] = {}
        # The keys it publishes and subscribes to, checked against protocol/dataflow.py.
        self.declared: dict[str, set[str]] = {"publishes": set(), "subscribes": set()}
        self.zenoh = open_session(config)
        self._token = self.zenoh.liveliness().declare_token(
            presence_key(self.session_id, role, self.id)
        )
        self.log.info(
            "joined the bus",
            extra=fields(
                session=self.session_id,
                node=self.id,
                mode=config.mode,
                connect=",".join(config.connect) or "-",
                listen=",".join(config.listen) if config.mode != "client" else "-",
            ),
        )

    # -- declarations -------------------------------------------------------------------
    def declare(self, direction: Direction, key: str) -> None:
        """Checks `key` against this role's row of protocol/dataflow.py (DataflowError if it
        is not there) and notes it; `output` and `input` call it, as must other publishers
        and subscribers of the node's session (the clock exchange)."""
        check(self.role, direction, key)
        self.declared[direction].add(key)

    def output(
        self, name: str, key: str, *, must_arrive: bool = True, keep: int | None = None
    ) -> Output:
        """A publisher. `must_arrive` (default) blocks instead of dropping under congestion.
        `keep` > 0 keeps the last `keep` messages for recovering inputs that missed them (a
        subscriber restarted, the router restarted); None: as this role's flow in
        protocol/dataflow.py says.

        Express: each message leaves at once rather than waiting to be batched. Every
        voxshape message is small and latency-bound; `voxshape bench sim` measured no
        difference in lockstep speed either way (the round trip is Python-bound)."""
        self.declare("publishes", key)
        if keep is None:
            flow = flow_of(self.role, "publishes", key)
            keep = flow.kept if flow is not None else 0
        congestion = zenoh.CongestionControl.BLOCK if must_arrive else zenoh.CongestionControl.DROP
        if keep > 0:
            publisher = declare_advanced_publisher(
                self.zenoh,
                key,
                congestion_control=congestion,
                express=True,
                cache=CacheConfig(max_samples=keep),
                sample_miss_detection=MissDetectionConfig(
                    heartbeat=None, sporadic_heartbeat=HEARTBEAT_S
                ),
                publisher_detection=True,
            )
        else:
            publisher = self.zenoh.declare_publisher(
                key, congestion_control=congestion, express=True
            )
        self._declared.append(publisher)
        return Output(self, name, key, publisher, kept=keep > 0)

    def input(self, name: str, key: str, *, recover: float | None = None) -> None:
        """Subscribes to `key` (wildcards allowed); messages arrive as Input(name, ...).

        `recover` > 0: what kept outputs published while this input could not hear them is
        fetched from them (their sequence numbers show the gaps), and on joining, what they
        published in the last `recover` seconds; messages that were lost for good anyway are
        counted as `missed.<input>`. Copies can arrive: tell them apart by message id. None:
        as this role's flow in protocol/dataflow.py says."""
        self.declare("subscribes", key)
        if recover is None:
            flow = flow_of(self.role, "subscribes", key)
            recover = flow.recover_s if flow is not None else 0.0

        def on_sample(sample: zenoh.Sample) -> None:
            key_text = str(sample.key_expr)
            try:
                expected = parse_key(key_text).message_type
                message = decode(sample.payload.to_bytes(), expected)
            except ProtocolError as e:
                self._reject(name, key_text, e)
                return
            except Exception as e:  # never let a bad sample kill zenoh's callback thread
                self._reject(name, key_text, ProtocolError("payload", repr(e)))
                return
            self.counters[f"received.{name}"] += 1
            self._queue.put(Input(name, key_text, message))

        if recover <= 0:
            self._declared.append(self.zenoh.declare_subscriber(key, on_sample))
            return

        def on_miss(miss: Miss) -> None:
            self.counters[f"missed.{name}"] += miss.nb
            self.log.warning("messages lost for good", extra=fields(input=name, count=miss.nb))

        subscriber = declare_advanced_subscriber(
            self.zenoh,
            key,
            on_sample,
            history=HistoryConfig(detect_late_publishers=True, max_age=recover),
            recovery=RecoveryConfig(periodic_queries=None, heartbeat=True),
            subscriber_detection=True,
        )
        self._declared.extend([subscriber, subscriber.sample_miss_listener(on_miss)])
        self._recovering[name] = (key, on_sample, recover)

    def fetch_history(self, name: str) -> None:
        """Asks the kept outputs again for the last `recover` seconds of a recovering input:
        zenoh's own query on joining can come back empty (about 1 in 20 when it meets the
        router dropping a killed peer). What comes are copies, behind live messages."""
        key, on_sample, seconds = self._recovering[name]
        self.counters[f"refetched.{name}"] += 1

        def on_reply(reply: zenoh.Reply) -> None:
            if reply.ok is not None and zenoh.KeyExpr(key).intersects(reply.ok.key_expr):
                on_sample(reply.ok)

        self.zenoh.get(
            f"{key}/{HISTORY_SUFFIX}?_time=[now(-{seconds:g}s)..]",
            on_reply,
            consolidation=zenoh.ConsolidationMode.NONE,
            accept_replies=zenoh.ReplyKeyExpr.ANY,
        )

    def watch_presence(self, role: str = "*", node: str = "*") -> None:
        """Presence events for nodes of the session, including those already present."""

        def on_token(sample: zenoh.Sample) -> None:
            parts = str(sample.key_expr).split("/")
            alive = sample.kind == zenoh.SampleKind.PUT
            self._queue.put(Presence(parts[-2], parts[-1], alive))

        key = presence_key(self.session_id, role, node)
        self._declared.append(
            self.zenoh.liveliness().declare_subscriber(key, on_token, history=True)
        )

    def _reject(self, name: str, key: str, error: ProtocolError) -> None:
        self.counters[f"rejected.{name}"] += 1
        n = self.counters[f"rejected.{name}"]
        if worth_logging(n):
            self.log.warning(
                "rejected a message",
                extra=fields(
                    input=name, key=key, field=error.field, problem=error.problem, count=n
                ),
            )

    # -- the loop -----------------------------------------------------------------------
    def events(self, tick: float | None = None, stats_every: float = 30.0) -> Iterator[Event]:
        """Inputs and presence changes as they arrive, a Tick every `tick` seconds, until stop()
        or SIGINT/SIGTERM."""
        restore = self._handle_signals()
        now = time.monotonic()
        next_tick = now + tick if tick else float("inf")
        next_stats, logged = now + stats_every, Counter()
        try:
            while not (self._signalled or self._stopping.is_set()):
                now = time.monotonic()
                if now >= next_stats:
                    if self.counters != logged:
                        self.log_stats()
                        logged = Counter(self.counters)
                    next_stats = now + stats_every
                if now >= next_tick:
                    next_tick = max(next_tick + tick, now)
                    yield Tick(time.time())
                    continue
                wake = min(next_tick, next_stats, now + SIGNAL_CHECK_S)
                try:
                    item = self._queue.get(timeout=wake - now)
                except queue.Empty:
                    continue
                if item is _STOP:
                    break
                yield item
        finally:
            restore()
            if self._signalled:
                self._stopping.set()

    def poll(self, timeout: float) -> Input | Presence | None:
        """The next input or presence change within `timeout` seconds, else None (no Ticks,
        no signal handling: for request/response code and tests)."""
        try:
            item = self._queue.get(timeout=timeout)
        except queue.Empty:
            return None
        if item is _STOP:
            self._queue.put(_STOP)  # keep events() stopping too
            return None
        return item

    def stop(self) -> None:
        self._stopping.set()
        self._queue.put(_STOP)

    def _handle_signals(self) -> Callable[[], object]:
        if threading.current_thread() is not threading.main_thread():
            return lambda: None
        previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}

        def on_signal(signum: int, _frame: object) -> None:
            # Only a flag: a handler that took the queue's lock could deadlock with the main
            # thread holding it (in get()); events() sees the flag within SIGNAL_CHECK_S.
            self._signalled = True
            self.log.info("stopping", extra=fields(signal=signal.Signals(signum).name))

        for s in previous:
            signal.signal(s, on_signal)
        return lambda: [signal.signal(s, h) for s, h in previous.items()]

    def log_stats(self) -> None:
        self.log.info("counters", extra=fields(**dict(sorted(self.counters.items()))))

    # -- shutdown -----------------------------------------------------------------------
    def close(self) -> None:
        for declared in reversed(self._declared):
            declared.undeclare()
        self._declared.clear()
        self._token.undeclare()
        self.zenoh.close()
        if self.counters:
            self.log_stats()
        # What it declared, without the `voxshape/<session>/` of every key: robot/r1/obs
        declared = {
            d: " ".join(sorted(k.split("/", 2)[-1] for k in keys))
            for d, keys in self.declared.items()
        }
        self.log.info("left the bus", extra=fields(node=self.id, **declared))

    def __enter__(self) -> Node:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

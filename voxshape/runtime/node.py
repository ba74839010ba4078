"""A service's handle on the bus: a small loop over typed events.

    with Node("sim", bus_config("sim", args)) as node:
        obs = node.advertise("obs", "r1")        # robot r1's observations
        node.subscribe("action", "r1")            # its actions, as Input(name="action")
        for event in node.events(tick=0.1):
            match event:
                case Input(name="action", message=action): ...
                case Tick(): obs.put(...)

A node names the topic and whose it is (a robot's or a teacher's id, "*" for all of the
session's); its key is built here alone (voxshape/protocol/keys.py), and checked against the role's
row of voxshape/protocol/dataflow.py, which says how it is delivered. Inputs are decoded strictly
with the type their key carries; a malformed message is counted and logged, never delivered and
never fatal. Outputs never wait for a slow subscriber and keep
their last N messages (zenoh's advanced publisher), as their topic's delivery in
voxshape/protocol/dataflow.py says; what must survive a stop or a restart of its subscriber or of
the router comes in on a recovering input (an advanced subscriber that fetches what it missed,
and on joining the last S seconds), as the role's flows say; the messages' ids tell a copy
from a new one. The node holds a liveliness token at
`voxshape/<session>/presence/<role>/<node>` while it lives, and `events()` ends on
SIGINT/SIGTERM/SIGHUP, after which leaving the `with` block closes everything cleanly.

The typed events, Output and the kept/recovering declarations are in flows.py; opening the
zenoh session, and BusError, in session.py; all are importable from here too.
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

import zenoh
from zenoh.ext import Miss

from voxshape.protocol import Message, ProtocolError, decode, parse_key, presence_key, session_keys
from voxshape.protocol.dataflow import ANY, Direction, check, delivery_of, flow_of
from voxshape.protocol.keys import SCOPES, message_key, robot_key, teacher_key
from voxshape.runtime.config import BusConfig
from voxshape.runtime.flows import (
    Event,
    Input,
    Output,
    Presence,
    Tick,
    kept_now,
    kept_publisher,
    query_history,
    recovering_subscriber,
)
from voxshape.runtime.logs import fields, worth_logging
from voxshape.runtime.session import BusError as BusError  # importable from here too
from voxshape.runtime.session import open_zenoh

SIGNAL_CHECK_S = 0.1  # events() notices SIGINT/SIGTERM/SIGHUP within this
# each stops a node cleanly: Ctrl-C, a stop (a launcher's, or its death), a terminal closed
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
_STOP = object()


def default_node_id(role: str) -> str:
    host = "".join(c if c.isalnum() or c in "_-" else "-" for c in socket.gethostname())
    return f"{role}-{host[:40]}-{os.getpid()}"


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
        self._signalled = False  # set by a stop signal: a plain flag, no lock to take
        self._declared: list = []
        self._published: dict[str, Output] = {}  # by key: publish()'s outputs
        self._recovering: dict[str, tuple[str, Callable[[zenoh.Sample], None], float]] = {}
        # The keys it publishes and subscribes to, checked against voxshape/protocol/dataflow.py.
        self.declared: dict[str, set[str]] = {"publishes": set(), "subscribes": set()}
        self.zenoh = open_zenoh(config)
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
    def subscribe(self, topic: str, of: str = ANY, *, recover: float | None = None) -> str:
        """Subscribes to `topic` of the robot or teacher `of` (ANY: all of the session's), as
        this role's row of voxshape/protocol/dataflow.py says; messages arrive as Input(topic, ...).
        Returns the key."""
        key = self.key(topic, of)
        self.input(topic, key, recover=recover)
        return key

    def advertise(self, topic: str, of: str, *, keep: int | None = None) -> Output:
        """The output of `topic` of the robot or teacher `of`, as this role's row says."""
        return self.output(topic, self.key(topic, of), keep=keep)

    def key(self, topic: str, of: str = ANY) -> str:
        """The key of `topic` (a robot's or a teacher's, voxshape/protocol/keys.py) of `of` here."""
        scope = next((s for s, topics in SCOPES.items() if topic in topics), "robot")
        make = robot_key if scope == "robot" else teacher_key
        return make(self.session_id, of, topic)  # ProtocolError names an unknown topic

    @property
    def everything(self) -> str:
        """The key expression of every message of the session (the logger's, listen's)."""
        return session_keys(self.session_id)

    @property
    def presences(self) -> str:
        """The key expression of every node's presence token in the session."""
        return presence_key(self.session_id)

    def declare(self, direction: Direction, key: str) -> None:
        """Checks `key` against this role's row of voxshape/protocol/dataflow.py (DataflowError if
        it is not there) and notes it; `output` and `input` call it, as must other publishers
        and subscribers of the node's session (the clock exchange)."""
        check(self.role, direction, key)
        self.declared[direction].add(key)

    def output(self, name: str, key: str, *, keep: int | None = None) -> Output:
        """A publisher, delivered as its topic's row of voxshape/protocol/dataflow.py DELIVERY says:
        a slow subscriber never makes it wait (what that one cannot take is dropped for it
        alone), and it keeps its last `keep` messages (None: the row's) for subscribers that
        missed them (dropped while slow, or published while they or the router restarted).

        Express: each message leaves at once rather than waiting to be batched. Every
        voxshape message is small and latency-bound; `benchmarks/sim.py` measured no
        difference in lockstep speed either way (the round trip is Python-bound)."""
        self.declare("publishes", key)
        delivery = delivery_of(key)
        keep = delivery.kept if keep is None else keep
        drop = zenoh.CongestionControl.DROP
        congestion = zenoh.CongestionControl.BLOCK if delivery.waits else drop
        if keep > 0:
            publisher = kept_publisher(self.zenoh, key, congestion, keep)
        else:
            publisher = self.zenoh.declare_publisher(
                key, congestion_control=congestion, express=True
            )
        self._declared.append(publisher)
        return Output(self.id, self.counters, name, key, publisher, kept=keep > 0)

    def publish(self, message: Message) -> None:
        """Puts `message` on its key (voxshape/protocol/keys.py: its type's topic, of its robot or
        teacher), through an output declared on first use, as its role's flow says (robots
        and teachers come and go)."""
        key = message_key(self.session_id, message)
        output = self._published.get(key)
        if output is None:
            output = self._published[key] = self.output(parse_key(key).name, key)
        output.put(message)

    def input(self, name: str, key: str, *, recover: float | None = None) -> None:
        """Subscribes to `key` (wildcards allowed); messages arrive as Input(name, ...).

        `recover` > 0: what kept outputs published while this input could not hear them is
        fetched from them (their sequence numbers show the gaps), and on joining, what they
        published in the last `recover` seconds; messages that were lost for good anyway are
        counted as `missed.<input>`. Copies can arrive: tell them apart by message id. None:
        as this role's flow in voxshape/protocol/dataflow.py says."""
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

        subscriber = recovering_subscriber(self.zenoh, key, on_sample, recover)
        self._declared.extend([subscriber, subscriber.sample_miss_listener(on_miss)])
        self._recovering[name] = (key, on_sample, recover)

    def fetch_history(self, name: str) -> None:
        """Asks the kept outputs again for the last `recover` seconds of a recovering input:
        zenoh's own query on joining can come back empty (about 1 in 20 when it meets the
        router dropping a killed peer). What comes are copies, behind live messages."""
        key, on_sample, seconds = self._recovering[name]
        self.counters[f"refetched.{name}"] += 1
        query_history(self.zenoh, key, on_sample, seconds)

    def latest(self, topic: str, of: str, timeout: float = 1.0) -> Message | None:
        """The newest message the kept outputs of `topic` of `of` hold, asked now and waited
        for (at most `timeout` seconds; None if none answered): what a node must know before
        it goes on, which its recovering input may bring only later."""
        found = []
        for sample in kept_now(self.zenoh, self.key(topic, of), timeout):
            try:
                expected = parse_key(str(sample.key_expr)).message_type
                found.append(decode(sample.payload.to_bytes(), expected))
            except ProtocolError as e:
                self._reject("latest", str(sample.key_expr), e)
        return max(found, key=lambda m: m.sent_at, default=None)

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
        or SIGINT/SIGTERM/SIGHUP."""
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

    def pending(self, limit: int) -> Iterator[Input | Presence]:
        """What arrived and was not taken yet, at most `limit` events, without waiting (after
        events() stopped: what came before the stop)."""
        for _ in range(limit):
            item = self.poll(0)
            if item is None:
                return
            yield item

    def deliver(self, event: object) -> None:
        """Puts an event of another source into this node's loop, after what came before it
        (a second zenoh session's samples: `voxshape ros2`'s robot); events() yields it."""
        self._queue.put(event)

    def stop(self) -> None:
        self._stopping.set()
        self._queue.put(_STOP)

    def _handle_signals(self) -> Callable[[], object]:
        if threading.current_thread() is not threading.main_thread():
            return lambda: None
        previous = {s: signal.getsignal(s) for s in STOP_SIGNALS}

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

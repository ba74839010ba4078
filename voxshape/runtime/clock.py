"""A teacher's side of the clock exchange with the arbiter, for any teacher client (the
`voxshape teach` client, the simulated teacher): the arbiter corrects utterance times with the
offset reported here, so a teacher whose clock is seconds off is still credited right.

    estimate = sync_clock(node, "ana")   # at start, then every minute or so (clocks drift)

NTP style (voxshape/services/arbiter/clocks.py has the whole picture): each probe leaves at t0 (this
clock), the arbiter stamps t1 and t2 (its clock), the reply arrives at t3 (this clock):
offset = ((t1 - t0) + (t2 - t3)) / 2 is the arbiter's clock minus this one, within +-rtt/2.
The exchange with the lowest round trip wins; one last probe reports it to the arbiter.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Callable
from typing import NamedTuple

import zenoh

from voxshape.protocol import (
    ClockProbe,
    ClockReply,
    ProtocolError,
    check_id,
    decode,
    encode,
    teacher_key,
)
from voxshape.runtime.node import Node

REPLY_WAIT = 0.5  # seconds to wait for each reply before counting the exchange lost


class ClockEstimate(NamedTuple):
    offset: float  # the arbiter's clock minus this one, seconds
    rtt: float  # round trip of the exchange it came from; the offset is within +-rtt/2


class ClockSyncError(RuntimeError):
    """No arbiter answered; the message says where it asked and what to check."""


def estimate_from(reply: ClockReply, t3: float) -> ClockEstimate:
    """One exchange's estimate, given when its reply arrived (t3, this clock)."""
    offset = ((reply.t1 - reply.t0) + (reply.t2 - t3)) / 2
    rtt = max(0.0, (t3 - reply.t0) - (reply.t2 - reply.t1))
    return ClockEstimate(offset, rtt)


def sync_clock(
    node: Node,
    teacher: str,
    n: int = 8,
    clock: Callable[[], float] = time.time,
    reply_wait: float = REPLY_WAIT,
) -> ClockEstimate:
    """`n` exchanges, one at a time, then a probe reporting the best to the arbiter; returns
    it. `clock` is this teacher's clock (a test can skew it). Uses its own subscriber, so the
    node's events are left alone. Raises ClockSyncError if no reply came at all; takes at
    most (n + 3) * reply_wait seconds."""
    check_id(teacher, "teacher")
    if n < 1:
        raise ValueError(f"n={n}: at least one exchange is needed")
    # queue.Queue: SimpleQueue's timed get can wait past its timeout (voxshape/runtime/node.py)
    replies: queue.Queue[tuple[ClockReply, float]] = queue.Queue()

    def on_reply(sample: zenoh.Sample) -> None:
        t3 = clock()
        # A reply this build cannot read is dropped: its exchange counts as lost.
        with contextlib.suppress(ProtocolError):
            replies.put((decode(sample.payload.to_bytes(), ClockReply), t3))

    session = node.zenoh
    probe_key = teacher_key(node.session_id, teacher, "clock")
    reply_key = teacher_key(node.session_id, teacher, "clock-reply")
    node.declare("publishes", probe_key)
    node.declare("subscribes", reply_key)
    subscriber = session.declare_subscriber(reply_key, on_reply)
    publisher = session.declare_publisher(
        probe_key, congestion_control=zenoh.CongestionControl.BLOCK, express=True
    )
    best: ClockEstimate | None = None
    try:
        exchanges = lost = 0
        while exchanges < n and lost < n + 2:
            estimate = _exchange(publisher, node.id, teacher, best, clock, replies, reply_wait)
            if estimate is None:
                lost += 1
                if best is None and lost >= 3:
                    break
                continue
            exchanges += 1
            if best is None or estimate.rtt < best.rtt:
                best = estimate
        if best is None:
            raise ClockSyncError(
                f"no arbiter answered on {probe_key} within {lost * reply_wait:g} s: is "
                f"`voxshape arbiter` running in session {node.session_id!r}?"
            )
        _exchange(publisher, node.id, teacher, best, clock, replies, reply_wait)  # the report
        return best
    finally:
        publisher.undeclare()
        subscriber.undeclare()


def _exchange(
    publisher: zenoh.Publisher,
    sender: str,
    teacher: str,
    best: ClockEstimate | None,
    clock: Callable[[], float],
    replies: queue.Queue[tuple[ClockReply, float]],
    wait: float,
) -> ClockEstimate | None:
    probe = ClockProbe(
        teacher=teacher,
        t0=clock(),
        offset=best.offset if best else None,
        rtt=best.rtt if best else None,
        sender=sender,
    )
    publisher.put(encode(probe))
    deadline = time.monotonic() + wait
    while (left := deadline - time.monotonic()) > 0:
        try:
            reply, t3 = replies.get(timeout=left)
        except queue.Empty:
            return None
        if reply.probe == probe.id:
            return estimate_from(reply, t3)
    return None


class ClockSync:
    """Keeps the arbiter told of a teacher's clock offset: an exchange at start and every
    `every` seconds (clocks drift), in a thread, so teaching goes on while an exchange waits
    for an arbiter that is not there yet. `synced` gets each estimate; `problem` is told once
    that no arbiter answers (exchanges go on every `retry` seconds) and when the exchange
    stops for good (the session closing)."""

    def __init__(
        self,
        node: Node,
        teacher: str,
        synced: Callable[[ClockEstimate], None],
        problem: Callable[[str], None],
        clock: Callable[[], float] = time.time,
        every: float = 60.0,
        retry: float = 1.0,
    ) -> None:
        self.node, self.teacher, self.clock = node, teacher, clock
        self.synced, self.problem = synced, problem
        self.every, self.retry = every, retry
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="clock-sync", daemon=True)

    def __enter__(self) -> ClockSync:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(timeout=5.0)

    def _run(self) -> None:
        warned = False
        while not self.stop.is_set():
            try:
                estimate = sync_clock(
                    self.node, self.teacher, n=4, clock=self.clock, reply_wait=0.3
                )
            except ClockSyncError as e:
                if not warned:
                    self.problem(str(e))
                    warned = True
                self.stop.wait(self.retry)
                continue
            except Exception as e:  # the session closing at shutdown, a bus error
                if not self.stop.is_set():
                    self.problem(f"clock exchange stopped: {e!r}")
                return
            self.synced(estimate)
            self.stop.wait(self.every)

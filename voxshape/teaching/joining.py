"""Joining a session as a teacher, the one way every teacher's node does it (the terminal
client, each browser of the web page, the simulated teacher): the notices it hears, the echo
of its own utterances, the clock exchange with the arbiter, and what it says, kept for a
speech service or arbiter that missed it (restarted, or the router was)."""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import ExitStack

from voxshape.protocol import AudioChunk, Message, Placed, Said, Utterance
from voxshape.runtime import Node, Output
from voxshape.runtime.clock import ClockEstimate, ClockSync

SAYS: dict[str, type[Message]] = {
    "utterance": Utterance,
    "said": Said,
    "audio": AudioChunk,
    "placed": Placed,  # a real robot is back at its start (the page's button)
}


def join_as_teacher(
    node: Node,
    stack: ExitStack,
    teacher: str,
    says: tuple[str, ...],
    *,
    synced: Callable[[ClockEstimate], None],
    problem: Callable[[str], None],
    clock: Callable[[], float] = time.time,
    echo: bool = True,
    kept: dict[str, int] | None = None,
) -> dict[type[Message], Output]:
    """Declares a teacher's inputs (its notices; with `echo`, its utterances as the bus
    carries them) and its outputs `says` (topics: utterance, said, audio, placed), and starts the
    clock exchange (closed with `stack`). What it says is kept as its flows in
    voxshape/protocol/dataflow.py say, unless `kept` says otherwise per topic. The outputs come by
    the type of message each carries."""
    if echo:
        node.subscribe("utterance", teacher)
    node.subscribe("notice", teacher)
    stack.enter_context(ClockSync(node, teacher, synced=synced, problem=problem, clock=clock))
    kept = kept or {}
    return {SAYS[topic]: node.advertise(topic, teacher, keep=kept.get(topic)) for topic in says}

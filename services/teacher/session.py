"""Joining a session as a teacher, the one way every teacher's node does it (the terminal
client, each browser of the web page, the simulated teacher): the notices it hears, the echo
of its own utterances, the clock exchange with the arbiter, and what it says, kept for a
speech service or arbiter that missed it (restarted, or the router was)."""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import ExitStack

from protocol import AudioChunk, Message, Said, Utterance, teacher_key
from services.runtime import Node, Output
from services.runtime.clock import ClockEstimate, ClockSync

# What a teacher says, kept: as much as the speech service and the arbiter ask for on
# rejoining (30 s; 50 ms a chunk of audio).
KEPT = {"utterance": 256, "said": 256, "audio": 800}
SAYS: dict[str, type[Message]] = {"utterance": Utterance, "said": Said, "audio": AudioChunk}


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
    carries them) and its outputs `says` (topics: utterance, said, audio), and starts the
    clock exchange (closed with `stack`). `kept` overrides KEPT per topic. The outputs come
    by the type of message each carries."""
    session = node.session_id
    if echo:
        node.input("utterance", teacher_key(session, teacher, "utterance"))
    node.input("notice", teacher_key(session, teacher, "notice"))
    stack.enter_context(ClockSync(node, teacher, synced=synced, problem=problem, clock=clock))
    keep = {**KEPT, **(kept or {})}
    return {
        SAYS[topic]: node.output(topic, teacher_key(session, teacher, topic), keep=keep[topic])
        for topic in says
    }

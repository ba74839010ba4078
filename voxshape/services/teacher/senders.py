"""Where `voxshape teach`'s messages come from: recordings on their schedule, the microphone,
or lines typed at a prompt or read from a script."""

from __future__ import annotations

import queue
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Protocol

import numpy as np

from voxshape.protocol import AudioChunk, Message, Vocabulary
from voxshape.protocol.messages import SAMPLE_RATE
from voxshape.runtime.audio import samples_to_pcm
from voxshape.teaching.sources import (
    Scheduled,
    new_stream_id,
    typed,
    typed_at_terminal,
    typed_lines,
)


class Sender(Protocol):
    """Where the messages to send come from: `due()` those to send now; `done` at the end."""

    done: bool

    def due(self) -> list[Message]: ...


class ScheduledSender:
    """WAV chunks, each when due."""

    def __init__(self, schedule: list[Scheduled]) -> None:
        self._schedule = schedule
        self._next = 0
        self._t0 = time.monotonic()

    @property
    def done(self) -> bool:
        return self._next >= len(self._schedule)

    def due(self) -> list[Message]:
        elapsed = time.monotonic() - self._t0
        out = []
        while not self.done and self._schedule[self._next].due_s <= elapsed:
            out.append(self._schedule[self._next].message)
            self._next += 1
        return out


class MicrophoneSender:
    """Chunks of the microphone as they come; never done (Ctrl-C ends it)."""

    done = False

    def __init__(self, captured: queue.SimpleQueue, teacher: str, robot: str) -> None:
        self._captured = captured
        self._teacher, self._robot = teacher, robot
        self._stream = new_stream_id("mic")
        self._seq = 0

    def due(self) -> list[Message]:
        out: list[Message] = []
        while True:
            try:
                samples, capture_time = self._captured.get_nowait()
            except queue.Empty:
                return out
            out.append(
                AudioChunk(
                    teacher=self._teacher,
                    robot=self._robot,
                    stream=self._stream,
                    seq=self._seq,
                    sample_rate=SAMPLE_RATE,
                    pcm=samples_to_pcm(np.asarray(samples)),
                    capture_time=capture_time,
                    final=False,
                )
            )
            self._seq += 1


class TypedSender:
    """Lines typed at a prompt, or read from a script on stdin, as they come."""

    def __init__(
        self,
        teacher: str,
        robot: str,
        language: str,
        via_speech: Callable[[], bool],
        vocabulary: Vocabulary,
        arrows: bool = False,
    ) -> None:
        """`via_speech()`: whether a line goes to the speech service now (else straight out as
        an utterance); `arrows`: at a terminal, arrow keys send commands."""
        self._lines: queue.SimpleQueue = queue.SimpleQueue()
        self._args = (teacher, robot, language)
        self._via_speech = via_speech
        self.done = False
        if sys.stdin.isatty():
            how = "; arrow keys steer" if arrows else ""
            print(f"type what you say to robot {robot}, one utterance per line{how} (Ctrl-D ends)")
            lines = typed_at_terminal(vocabulary, language, arrows)
        else:
            lines = typed_lines(iter(sys.stdin.readline, ""))
        threading.Thread(target=self._read, args=(lines,), daemon=True).start()

    def _read(self, lines: Iterator[str]) -> None:
        for text in lines:
            self._lines.put(text)
        self._lines.put(None)

    def due(self) -> list[Message]:
        out: list[Message] = []
        while True:
            try:
                text = self._lines.get_nowait()
            except queue.Empty:
                return out
            if text is None:
                self.done = True
                return out
            text = text[:500]
            teacher, robot, language = self._args
            out.append(typed(text, teacher, robot, language, time.time(), self._via_speech()))

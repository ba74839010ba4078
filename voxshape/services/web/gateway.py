"""The web page's gateway, pure (no zenoh, no aiohttp): one logged-in browser's JSON and audio
frames -> protocol messages, and what its teacher is shown (Teaching).

The WebSocket protocol is docs/web.md's. In short: a browser logs in, probes the gateway's
clock, types words ("say") and talks (push-to-talk: "talk" start, binary audio frames, "talk"
stop); it is sent a welcome (map, vocabulary, robots), the robots' observations (at most
`OBS_HZ` a second per robot, the latest winning), episodes, feedback, its teaching statistics,
the learning curve, one notice line per utterance (the very line `voxshape teach` shows), and
the robots' questions ("which way?") with who answered them.

The rest of the gateway: frames.py reads what a browser sends, browser_clock.py its clock,
page_json.py makes what it is sent, robots.py the robots' stream that every page shares.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field, replace
from typing import Any

from voxshape.protocol import (
    AudioChunk,
    Message,
    Placed,
    ProtocolError,
    TeacherNotice,
    TeachingStats,
    Utterance,
    check_id,
    encode,
)
from voxshape.protocol.messages import MAX_CHUNK_BYTES, SAMPLE_RATE
from voxshape.protocol.vocabulary import LANGUAGES
from voxshape.runtime.limits import TokenBucket
from voxshape.services.web.browser_clock import BrowserClock
from voxshape.services.web.frames import BrowserError, finite_number
from voxshape.services.web.page_json import notice_json, stats_json
from voxshape.services.web.robots import Robots
from voxshape.teaching.board import Board
from voxshape.teaching.sources import new_stream_id, typed

AUDIO_HEADER = struct.Struct("<d")  # capture time of the first sample, browser ms


AUDIO_BURST_S = 3.0  # audio seconds a teacher may send ahead of real time


@dataclass
class Talk:
    """One push-to-talk press: one audio stream."""

    robot: str
    stream: str = field(default_factory=lambda: new_stream_id("web"))
    seq: int = 0
    end: float | None = None  # gateway seconds at the end of the audio so far


@dataclass
class FrameOutcome:
    """What a browser's frame gives: messages for the bus, JSON for the browser."""

    messages: list[Message] = field(default_factory=list)
    replies: list[dict[str, Any]] = field(default_factory=list)


class Teaching:
    """One logged-in browser: its teacher, watched robot, clock, push-to-talk stream, and its
    Board (voxshape/teaching/board.py), so its notice lines are the terminal client's."""

    def __init__(
        self,
        teacher: str,
        robots: Robots,
        board: Board,
        language: str = "en",
        audio_budget: TokenBucket | None = None,
    ) -> None:
        self.teacher = teacher
        self.robots = robots
        self.board = board
        self.language = language
        # seconds of audio: about real time, shared by the teacher's pages
        self.audio_budget = audio_budget or TokenBucket(1.0, AUDIO_BURST_S)
        self.robot: str | None = None  # watched: the first seen unless the page says
        self.clock = BrowserClock()
        self.talk: Talk | None = None

    def _robot(self, data: dict[str, Any]) -> str:
        robot = data.get("robot") or self.robot or (self.robots.seen or [None])[0]
        if robot is None:
            raise BrowserError(f"{data.get('type')}: no robot is running yet")
        try:
            return check_id(robot, "robot")
        except ProtocolError as e:
            raise BrowserError(f"{data.get('type')}: {e.problem}") from None

    def text(self, data: dict[str, Any], now_s: float, now_mono: float) -> FrameOutcome:
        """A JSON message of the browser; BrowserError if it cannot be used."""
        kind = data.get("type")
        if kind == "clock":
            return FrameOutcome(replies=[self.clock.probe(data, now_s)])
        if kind == "watch":
            self.robot = self._robot(data)
            return FrameOutcome()
        if kind == "say":
            return self._say(data, now_s, now_mono)
        if kind == "talk":
            return self._talk(data, now_s)
        if kind == "placed":  # a real robot is back at its start (voxshape ros2 waits)
            return FrameOutcome(
                messages=[_checked(Placed(teacher=self.teacher, robot=self._robot(data)))]
            )
        if kind == "login":
            raise BrowserError("already logged in")
        raise BrowserError(f"unknown message type {kind!r}: clock, watch, say, talk, placed")

    def _say(self, data: dict[str, Any], now_s: float, now_mono: float) -> FrameOutcome:
        text = data.get("text")
        if not isinstance(text, str) or not text.strip():
            raise BrowserError("say: text must be a non-empty string")
        if len(text) > 500:
            raise BrowserError("say: text is longer than 500 characters")
        language = data.get("language") or self.language
        if language not in LANGUAGES:
            raise BrowserError(f"say: language must be one of {', '.join(LANGUAGES)}")
        onset = data.get("onset")
        at = now_s if onset is None else self.clock.to_gateway(finite_number(data, "onset"), now_s)
        utterance = typed(text.strip(), self.teacher, self._robot(data), language, at, False)
        assert isinstance(utterance, Utterance)
        utterance = _checked(replace(utterance, recognized_at=now_s))
        self.board.sent(utterance, now_mono)
        return FrameOutcome(messages=[utterance])

    def _talk(self, data: dict[str, Any], now_s: float) -> FrameOutcome:
        state = data.get("state")
        if state == "start":
            out = self._stop(now_s)  # a press without its release ends the earlier stream
            self.talk = Talk(self._robot(data))
            return out
        if state == "stop":
            return self._stop(now_s)
        raise BrowserError("talk: state must be start or stop")

    def _stop(self, now_s: float) -> FrameOutcome:
        talk, self.talk = self.talk, None
        if talk is None:
            return FrameOutcome()
        return FrameOutcome(messages=[self._chunk(talk, b"", talk.end or now_s, final=True)])

    def audio(self, frame: bytes, now_s: float) -> FrameOutcome:
        """A binary frame: 8 bytes of capture time (float64 LE, browser ms), int16 LE PCM."""
        if self.talk is None:
            raise BrowserError('audio outside a press: send {"type": "talk", "state": "start"}')
        if len(frame) < AUDIO_HEADER.size or (len(frame) - AUDIO_HEADER.size) % 2:
            raise BrowserError("audio: 8 bytes of capture time, then 16-bit samples")
        (browser_ms,) = AUDIO_HEADER.unpack_from(frame)
        if not math.isfinite(browser_ms):
            raise BrowserError("audio: the capture time is not a finite number")
        pcm = frame[AUDIO_HEADER.size :]
        seconds = len(pcm) / 2 / SAMPLE_RATE
        if not self.audio_budget.take(now_s, seconds):
            raise BrowserError(
                f"audio: faster than real time (at most {AUDIO_BURST_S:g} s ahead): "
                "this frame was dropped"
            )
        if self.clock.offset_ms is None:  # no clock yet: the frame was captured just now
            at = now_s - seconds
        else:
            at = self.clock.to_gateway(browser_ms, now_s)
        talk, messages = self.talk, []
        for start in range(0, len(pcm), MAX_CHUNK_BYTES):  # a chunk holds 1 s at most
            piece = pcm[start : start + MAX_CHUNK_BYTES]
            messages.append(self._chunk(talk, piece, at + start / 2 / SAMPLE_RATE, final=False))
        talk.end = at + seconds
        return FrameOutcome(messages=messages)

    def _chunk(self, talk: Talk, pcm: bytes, at: float, final: bool) -> AudioChunk:
        chunk = AudioChunk(
            teacher=self.teacher,
            robot=talk.robot,
            stream=talk.stream,
            seq=talk.seq,
            sample_rate=SAMPLE_RATE,
            pcm=pcm,
            capture_time=at,
            final=final,
        )
        talk.seq += 1
        return _checked(chunk)

    # -- what the teacher is shown ---------------------------------------------------------
    def notice(self, notice: TeacherNotice, now_mono: float) -> list[dict[str, Any]]:
        return [notice_json(s) for s in self.board.notice(notice, now_mono)]

    def recognized(self, utterance: Utterance, now_mono: float) -> list[dict[str, Any]]:
        """This teacher's utterance as the bus carried it (speech's, or the echo of a typed
        one): its notice is awaited, or shown now if it came first."""
        return [notice_json(s) for s in self.board.recognized(utterance, now_mono)]

    def tick(self, now_mono: float) -> list[dict[str, Any]]:
        shown = self.board.tick(now_mono)
        return [notice_json(s) for s in shown if s.event in ("notice", "no_answer")]

    def stats(self, stats: TeachingStats) -> dict[str, Any]:
        return stats_json(stats, self.teacher)


def _checked(message: Message) -> Any:
    """The message if the codec would send it; BrowserError naming the field if not."""
    try:
        encode(message)
    except ProtocolError as e:
        raise BrowserError(f"{e.field}: {e.problem}") from None
    return message

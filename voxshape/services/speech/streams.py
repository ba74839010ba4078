"""Every teacher's audio streams: chunk order, the teacher's clock, limits, and segments.

A stream is one (teacher, stream id) pair; its chunks are numbered by `seq`. Each chunk's
`capture_time` (teacher clock at its first sample) anchors the stream's samples to the
teacher's clock, so an utterance's onset and end are the capture time of the chunk they fall
in plus the sample offset within it: drift and gaps between chunks do not accumulate.

Problems are counted and reported, never fatal: a chunk whose teacher differs from its key's,
one that repeats or goes back in `seq` (dropped), a gap in `seq` (the utterance in progress
ends there), an empty chunk, too many streams at once (refused), a stream that falls silent
without its final chunk (ended after `idle_timeout_s`).
"""

from __future__ import annotations

import bisect
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from voxshape.protocol import AudioChunk
from voxshape.protocol.messages import SAMPLE_RATE
from voxshape.runtime.audio import AudioError, pcm_to_samples
from voxshape.runtime.settings import option
from voxshape.services.speech.segmenter import Segment, Segmenter, SegmenterConfig

Report = Callable[[str, str], None]  # (problem kind, detail) -> None


@dataclass(frozen=True)
class StreamLimits:
    max_streams: int = option(64, "teachers' audio streams at once")
    idle_timeout_s: float = option(
        5.0, "seconds after which a stream without its final chunk is ended", flag="--idle-timeout"
    )


@dataclass(frozen=True)
class SpeechSegment:
    """An utterance of a teacher to a robot; onset and end on the teacher's clock."""

    teacher: str
    robot: str
    stream: str
    onset: float
    end: float
    samples: np.ndarray


@dataclass
class _Stream:
    robot: str
    segmenter: Segmenter
    next_seq: int
    last_seen: float
    anchors: list[tuple[int, float]] = field(default_factory=list)  # (sample, capture time)

    def time_at(self, sample: int) -> float:
        """Teacher-clock time of a sample of this stream."""
        i = bisect.bisect_right(self.anchors, (sample, float("inf"))) - 1
        index, capture_time = self.anchors[max(i, 0)]
        return capture_time + (sample - index) / SAMPLE_RATE

    def prune(self, keep_samples: int) -> None:
        """Forgets anchors no segment can start before anymore (keeps one at or before)."""
        horizon = self.segmenter.position - keep_samples
        i = bisect.bisect_right(self.anchors, (horizon, float("inf"))) - 1
        if i > 0:
            del self.anchors[:i]


class AudioStreams:
    def __init__(
        self,
        segmenter_config: SegmenterConfig | None = None,
        limits: StreamLimits | None = None,
        counters: Counter[str] | None = None,
        report: Report | None = None,
    ) -> None:
        self.segmenter_config = segmenter_config or SegmenterConfig()
        self.limits = limits or StreamLimits()
        self.counters: Counter[str] = counters if counters is not None else Counter()
        self._report = report or (lambda kind, detail: None)
        self._streams: dict[tuple[str, str], _Stream] = {}
        c = self.segmenter_config
        self._keep_samples = int((c.max_speech_s + c.pre_roll_s + c.hangover_s + 1) * SAMPLE_RATE)

    def __len__(self) -> int:
        return len(self._streams)

    def _problem(self, kind: str, detail: str) -> None:
        self.counters[f"audio.{kind}"] += 1
        self._report(kind, detail)

    def on_chunk(self, teacher: str, chunk: AudioChunk, now: float) -> list[SpeechSegment]:
        """A chunk that arrived on `teacher`'s audio key at `now` (service clock, seconds)."""
        if chunk.teacher != teacher:
            self._problem(
                "wrong_teacher",
                f"chunk of teacher {chunk.teacher!r} on teacher {teacher!r}'s key: dropped "
                "(a client publishes on its own teacher's key)",
            )
            return []
        key = (teacher, chunk.stream)
        stream = self._streams.get(key)
        if stream is None:
            if len(self._streams) >= self.limits.max_streams:
                self._problem(
                    "too_many_streams",
                    f"{len(self._streams)} streams open, the limit: stream {chunk.stream!r} of "
                    f"{teacher!r} refused (end streams with a final chunk)",
                )
                return []
            if chunk.seq != 0:
                self._problem(
                    "joined_late", f"stream {chunk.stream!r} of {teacher!r} starts at {chunk.seq}"
                )
            stream = _Stream(chunk.robot, Segmenter(self.segmenter_config), chunk.seq, now)
            self._streams[key] = stream
        if chunk.seq < stream.next_seq:
            self._problem(
                "out_of_order",
                f"chunk {chunk.seq} of stream {chunk.stream!r} of {teacher!r} came after "
                f"{stream.next_seq - 1}: dropped",
            )
            return []
        out: list[SpeechSegment] = []
        if chunk.seq > stream.next_seq:
            self._problem(
                "gap",
                f"chunks {stream.next_seq}-{chunk.seq - 1} of stream {chunk.stream!r} of "
                f"{teacher!r} never arrived: the utterance in progress ends there",
            )
            out += [self._speech(key, stream, s) for s in stream.segmenter.flush()]
        stream.next_seq = chunk.seq + 1
        stream.last_seen = now
        stream.robot = chunk.robot
        try:
            samples = pcm_to_samples(chunk.pcm)
        except AudioError as e:  # the codec refuses odd sizes already; kept for direct use
            self._problem("malformed", str(e))
            samples = np.zeros(0, dtype=np.int16)
        if len(samples) == 0 and not chunk.final:
            self._problem("empty", f"an empty chunk in stream {chunk.stream!r} of {teacher!r}")
        stream.anchors.append((stream.segmenter.position, chunk.capture_time))
        segments = stream.segmenter.feed(samples)
        if chunk.final:
            segments += stream.segmenter.flush()
        out += [self._speech(key, stream, s) for s in segments]
        if chunk.final:
            self._close(key)
        else:
            stream.prune(self._keep_samples)
        return out

    def on_tick(self, now: float) -> list[SpeechSegment]:
        """Ends the streams idle for longer than the limit (their final chunk never came)."""
        out = []
        for key, stream in list(self._streams.items()):
            if now - stream.last_seen > self.limits.idle_timeout_s:
                self._problem(
                    "stream_timed_out",
                    f"stream {key[1]!r} of {key[0]!r} sent nothing for "
                    f"{self.limits.idle_timeout_s:g} s and no final chunk: ended",
                )
                out += [self._speech(key, stream, s) for s in stream.segmenter.flush()]
                self._close(key)
        return out

    def close(self) -> list[SpeechSegment]:
        """Ends every stream (the service is stopping)."""
        out = []
        for key, stream in list(self._streams.items()):
            out += [self._speech(key, stream, s) for s in stream.segmenter.flush()]
            self._close(key)
        return out

    def _close(self, key: tuple[str, str]) -> None:
        stream = self._streams.pop(key)
        self.counters.update(stream.segmenter.counters)

    def _speech(self, key: tuple[str, str], stream: _Stream, segment: Segment) -> SpeechSegment:
        onset = stream.time_at(segment.start)
        end = max(onset, stream.time_at(segment.end))
        return SpeechSegment(key[0], stream.robot, key[1], onset, end, segment.samples)

"""Voice activity detection and endpointing of one audio stream (pure: samples in, segments out).

Energy against an adaptive noise floor, in 10 ms frames:

- the noise floor is a low percentile of the levels of the last few seconds. A stream that
  begins loud has no quiet frames to learn from yet: in its first `warmup_s`, if the level
  varies by `start_db` or more (syllables), the floor is capped at `floor_ceiling_dbfs` so the
  speech is heard; if it holds steady (a fan, a motor), it is the floor;
- speech starts when most of a few consecutive frames are `start_db` above the floor, and goes
  on while frames stay `stop_db` above it (hysteresis); `hangover_s` of quiet ends it;
- a segment carries its speech bounds (sample indices of the stream) and the audio around them
  (`pre_roll_s` before, up to `post_roll_s` after), which recognizers need as context;
- bursts shorter than `min_speech_s` are dropped (clicks), speech longer than `max_speech_s`
  is cut there (bounded memory and latency).
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass

import numpy as np

from voxshape.protocol.messages import SAMPLE_RATE
from voxshape.runtime.audio import FRAME_SAMPLES, level_dbfs


@dataclass(frozen=True)
class SegmenterConfig:
    start_db: float = 10.0  # speech starts this far above the noise floor
    stop_db: float = 6.0  # and goes on while this far above it
    min_speech_dbfs: float = -55.0  # never speech below this level, however quiet the floor
    floor_ceiling_dbfs: float = -35.0  # the floor estimate's cap during the warm-up
    warmup_s: float = 0.5
    floor_window_s: float = 3.0
    floor_percentile: float = 10.0
    start_frames: int = 3  # loud frames among the last `start_window` to start speech
    start_window: int = 5
    hangover_s: float = 0.3
    min_speech_s: float = 0.12
    max_speech_s: float = 8.0
    pre_roll_s: float = 0.25
    post_roll_s: float = 0.25

    def __post_init__(self) -> None:
        if not 0 < self.stop_db <= self.start_db:
            raise ValueError("need 0 < stop_db <= start_db")
        if not 0 < self.start_frames <= self.start_window:
            raise ValueError("need 0 < start_frames <= start_window")
        if not 0 < self.min_speech_s < self.max_speech_s:
            raise ValueError("need 0 < min_speech_s < max_speech_s")
        durations = (self.hangover_s, self.pre_roll_s, self.post_roll_s, self.warmup_s)
        if min(*durations, self.floor_window_s) < 0:
            raise ValueError("durations must be >= 0")


@dataclass(frozen=True)
class Segment:
    """Speech from sample `start` to `end` (exclusive) of the stream; `samples` is the audio
    from `audio_start`, a little before `start`, to a little after `end`."""

    start: int
    end: int
    audio_start: int
    samples: np.ndarray
    cut: bool = False  # ended by max_speech_s or a flush, not by quiet

    @property
    def duration(self) -> float:
        return (self.end - self.start) / SAMPLE_RATE


def _frames(seconds: float) -> int:
    return round(seconds * SAMPLE_RATE / FRAME_SAMPLES)


class Segmenter:
    """Feed it consecutive samples of one stream; it returns each utterance once it ended."""

    def __init__(self, config: SegmenterConfig | None = None) -> None:
        self.config = c = config or SegmenterConfig()
        self.counters: Counter[str] = Counter()
        self.position = 0  # samples consumed so far
        self._pending = np.zeros(0, dtype=np.int16)  # less than a frame, not yet consumed
        self._levels: deque[float] = deque(maxlen=max(1, _frames(c.floor_window_s)))
        # idle: recent frames (start sample, audio, loud) for the pre-roll and the start rule
        self._recent: deque[tuple[int, np.ndarray, bool]] = deque(
            maxlen=_frames(c.pre_roll_s) + c.start_window
        )
        self._speaking = False
        self._audio: list[np.ndarray] = []
        self._audio_start = self._speech_start = self._last_active_end = 0
        self._quiet_frames = 0

    @property
    def speaking(self) -> bool:
        return self._speaking

    def floor_dbfs(self) -> float:
        c = self.config
        if not self._levels:
            return c.floor_ceiling_dbfs
        floor = float(np.percentile(self._levels, c.floor_percentile))
        warming_up = self.position < c.warmup_s * SAMPLE_RATE
        if warming_up and max(self._levels) - min(self._levels) >= c.start_db:
            return min(floor, c.floor_ceiling_dbfs)
        return floor

    def feed(self, samples: np.ndarray) -> list[Segment]:
        """Consumes `samples` (int16) and returns the segments that ended within them."""
        data = np.concatenate([self._pending, np.asarray(samples, dtype=np.int16)])
        whole = len(data) - len(data) % FRAME_SAMPLES
        self._pending = data[whole:]
        out: list[Segment] = []
        for i in range(0, whole, FRAME_SAMPLES):
            segment = self._frame(data[i : i + FRAME_SAMPLES])
            if segment is not None:
                out.append(segment)
        return out

    def flush(self) -> list[Segment]:
        """The stream ended or broke off: ends the current utterance with what there is."""
        out = []
        if len(self._pending):
            segment = self._frame(self._pending)
            self._pending = np.zeros(0, dtype=np.int16)
            if segment is not None:
                out.append(segment)
        if self._speaking:
            segment = self._end(cut=True)
            if segment is not None:
                out.append(segment)
        self._recent.clear()
        return out

    def skip(self, n_samples: int) -> list[Segment]:
        """`n_samples` are missing from the stream (lost chunks): ends the current utterance
        and moves the stream position past the gap."""
        out = self.flush()
        self.position += n_samples
        return out

    # -- one frame ------------------------------------------------------------------------
    def _frame(self, frame: np.ndarray) -> Segment | None:
        c = self.config
        start = self.position
        self.position += len(frame)
        level = level_dbfs(frame)
        floor = self.floor_dbfs()
        self._levels.append(level)
        if not self._speaking:
            loud = level > max(floor + c.start_db, c.min_speech_dbfs)
            self._recent.append((start, frame, loud))
            window = list(self._recent)[-c.start_window :]
            if sum(f[2] for f in window) >= c.start_frames:
                self._begin(first_loud=next(f[0] for f in window if f[2]))
            return None
        self._audio.append(frame)
        if level > max(floor + c.stop_db, c.min_speech_dbfs):
            self._last_active_end = self.position
            self._quiet_frames = 0
        else:
            self._quiet_frames += 1
        if self._quiet_frames >= max(1, _frames(c.hangover_s)):
            return self._end(cut=False)
        if self.position - self._speech_start >= c.max_speech_s * SAMPLE_RATE:
            self.counters["segments.cut_at_max_length"] += 1
            return self._end(cut=True)
        return None

    def _begin(self, first_loud: int) -> None:
        pre_roll = _frames(self.config.pre_roll_s) * FRAME_SAMPLES
        kept = [(s, f) for s, f, _ in self._recent if s >= first_loud - pre_roll]
        self._audio = [f for _, f in kept]
        self._audio_start = kept[0][0]
        self._speech_start = first_loud
        self._last_active_end = self.position
        self._quiet_frames = 0
        self._speaking = True
        self._recent.clear()

    def _end(self, cut: bool) -> Segment | None:
        c = self.config
        self._speaking = False
        audio = np.concatenate(self._audio) if self._audio else np.zeros(0, dtype=np.int16)
        self._audio = []
        stop = min(
            self._last_active_end + round(c.post_roll_s * SAMPLE_RATE),
            self._audio_start + len(audio),
        )
        # the quiet after the utterance is the next one's pre-roll
        tail_start = max(self._last_active_end, self._audio_start)
        tail = audio[tail_start - self._audio_start :]
        for i in range(0, len(tail) - len(tail) % FRAME_SAMPLES, FRAME_SAMPLES):
            self._recent.append((tail_start + i, tail[i : i + FRAME_SAMPLES], False))
        if self._last_active_end - self._speech_start < c.min_speech_s * SAMPLE_RATE:
            self.counters["segments.too_short"] += 1
            return None
        self.counters["segments"] += 1
        return Segment(
            start=self._speech_start,
            end=self._last_active_end,
            audio_start=self._audio_start,
            samples=audio[: stop - self._audio_start],
            cut=cut,
        )

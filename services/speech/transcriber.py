"""The speech service's core (no bus): messages in, Utterance messages out.

`AudioTranscriber`: audio chunks -> streams -> segments -> an audio engine -> utterances.
`MockTranscriber`: said text -> the mock engine -> utterances, each when its latency is due.
Times: `now` is the service's wall clock (`recognized_at`); onsets and ends stay on the
teacher's clock.
"""

from __future__ import annotations

import heapq
import itertools
from collections import Counter
from dataclasses import replace

from protocol import Alternative, AudioChunk, Said, Utterance
from services.speech.engines import Recognizer
from services.speech.mock import MockRecognizer
from services.speech.streams import AudioStreams, Report, SpeechSegment


class AudioTranscriber:
    def __init__(
        self, recognizer: Recognizer, streams: AudioStreams, report: Report | None = None
    ) -> None:
        self.recognizer = recognizer
        self.streams = streams
        self.counters = streams.counters
        self._report = report or (lambda kind, detail: None)

    def on_audio(self, teacher: str, chunk: AudioChunk, now: float) -> list[Utterance]:
        return self._recognize_all(self.streams.on_chunk(teacher, chunk, now), now)

    def on_tick(self, now: float) -> list[Utterance]:
        return self._recognize_all(self.streams.on_tick(now), now)

    def close(self, now: float) -> list[Utterance]:
        return self._recognize_all(self.streams.close(), now)

    def _recognize_all(self, segments: list[SpeechSegment], now: float) -> list[Utterance]:
        out = []
        for segment in segments:
            utterance = self._recognize(segment, now)
            if utterance is not None:
                out.append(utterance)
        return out

    def _recognize(self, segment: SpeechSegment, now: float) -> Utterance | None:
        self.counters["speech.segments"] += 1
        try:
            result = self.recognizer.recognize(segment.samples)
        except Exception as e:  # an engine failure loses one utterance, never the service
            self.counters["speech.engine_errors"] += 1
            self._report("engine_error", f"{self.recognizer.engine} failed on an utterance: {e!r}")
            return None
        if result is None:
            self.counters["speech.rejected"] += 1
            return None
        self.counters["speech.utterances"] += 1
        return Utterance(
            teacher=segment.teacher,
            robot=segment.robot,
            text=result.text,
            confidence=result.confidence,
            onset=segment.onset,
            end=segment.end,
            recognized_at=now,
            engine=self.recognizer.engine,
            language=self.recognizer.language,  # type: ignore[arg-type]
            alternatives=tuple(
                Alternative(text=text, confidence=confidence)
                for text, confidence in result.alternatives[:10]
            ),
        )


class MockTranscriber:
    def __init__(self, mock: MockRecognizer, counters: Counter[str] | None = None) -> None:
        self.mock = mock
        self.counters: Counter[str] = counters if counters is not None else Counter()
        self._due: list[tuple[float, int, Utterance]] = []  # heap by due time
        self._order = itertools.count()

    def on_said(self, teacher: str, said: Said, now: float) -> list[Utterance]:
        """Schedules what the mock hears of `said`; returns the results already due."""
        if said.teacher != teacher:
            self.counters["said.wrong_teacher"] += 1
            return []
        for heard in self.mock.hear(said.text, said.language):
            utterance = Utterance(
                teacher=said.teacher,
                robot=said.robot,
                text=heard.text,
                confidence=heard.confidence,
                onset=said.onset,
                end=said.end,
                recognized_at=now,  # replaced when due
                engine=self.mock.engine,
                language=said.language,
                alternatives=(),
            )
            heapq.heappush(self._due, (now + heard.delay_s, next(self._order), utterance))
        self.counters.update(self.mock.counters)
        self.mock.counters.clear()
        return self.on_tick(now)

    def on_tick(self, now: float) -> list[Utterance]:
        out = []
        while self._due and self._due[0][0] <= now:
            due, _, utterance = heapq.heappop(self._due)
            out.append(_recognized_at(utterance, due))
        return out

    def close(self, now: float) -> list[Utterance]:
        """Everything still pending, at once (the service is stopping)."""
        out = [_recognized_at(u, max(now, due)) for due, _, u in sorted(self._due)]
        self._due.clear()
        return out


def _recognized_at(utterance: Utterance, when: float) -> Utterance:
    return replace(utterance, recognized_at=when)

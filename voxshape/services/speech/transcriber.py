"""The speech service's core (no bus): messages in, Utterance messages out, and a
TeacherNotice ("not_recognized") for each stretch of speech the engine rejected, so the
teacher hears that something was heard and not understood.

`AudioTranscriber`: audio chunks -> streams -> segments -> an audio engine -> utterances.
`MockTranscriber`: said text -> the mock engine -> utterances, each when its latency is due.
Times: `now` is the service's wall clock (`recognized_at`); onsets and ends stay on the
teacher's clock.
"""

from __future__ import annotations

import hashlib
import heapq
import itertools
from collections import Counter
from dataclasses import replace

from voxshape.protocol import Alternative, AudioChunk, Said, TeacherNotice, Utterance
from voxshape.protocol.messages import new_message_id
from voxshape.services.speech.mock import MockRecognizer
from voxshape.services.speech.recognizer import Recognizer
from voxshape.services.speech.streams import AudioStreams, Report, SpeechSegment

Recognized = Utterance | TeacherNotice


def not_recognized(teacher: str, robot: str, engine: str) -> TeacherNotice:
    """The notice of speech the engine heard and rejected (no phrase of the vocabulary)."""
    return TeacherNotice(
        teacher=teacher,
        robot=robot,
        utterance=new_message_id(),
        kind="not_recognized",
        meaning=None,
        text=f"not recognized: {engine} heard speech but no phrase of the vocabulary; "
        "say it again (`voxshape vocabulary` lists them)",
    )


class AudioTranscriber:
    def __init__(
        self, recognizer: Recognizer, streams: AudioStreams, report: Report | None = None
    ) -> None:
        self.recognizer = recognizer
        self.streams = streams
        self.counters = streams.counters
        self._report = report or (lambda kind, detail: None)

    def on_audio(self, teacher: str, chunk: AudioChunk, now: float) -> list[Recognized]:
        return self._recognize_all(self.streams.on_chunk(teacher, chunk, now), now)

    def on_tick(self, now: float) -> list[Recognized]:
        return self._recognize_all(self.streams.on_tick(now), now)

    def close(self, now: float) -> list[Recognized]:
        return self._recognize_all(self.streams.close(), now)

    def _recognize_all(self, segments: list[SpeechSegment], now: float) -> list[Recognized]:
        out = []
        for segment in segments:
            utterance = self._recognize(segment, now)
            if utterance is not None:
                out.append(utterance)
        return out

    def _recognize(self, segment: SpeechSegment, now: float) -> Recognized | None:
        self.counters["speech.segments"] += 1
        try:
            result = self.recognizer.recognize(segment.samples)
        except Exception as e:  # an engine failure loses one utterance, never the service
            self.counters["speech.engine_errors"] += 1
            self._report("engine_error", f"{self.recognizer.engine} failed on an utterance: {e!r}")
            return None
        if result is None:
            self.counters["speech.rejected"] += 1
            return not_recognized(segment.teacher, segment.robot, self.recognizer.engine)
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
            language=self.recognizer.language,
            alternatives=tuple(
                Alternative(text=text, confidence=confidence)
                for text, confidence in result.alternatives[:10]
            ),
        )


class Unheard:
    """Input the running engine cannot hear: said text reaching an audio engine, or audio
    reaching the mock engine. Each teacher is told once, with what to do; all is counted."""

    def __init__(self, engine: str, counters: Counter[str] | None = None) -> None:
        self.engine = engine
        self.counters: Counter[str] = counters if counters is not None else Counter()
        self.told: set[str] = set()

    def on_input(self, teacher: str, robot: str, kind: str) -> list[TeacherNotice]:
        """`kind` is "said" or "audio"; a notice the first time `teacher` sends it."""
        self.counters[f"unheard.{kind}"] += 1
        if teacher in self.told:
            return []
        self.told.add(teacher)
        if kind == "said":
            what = (
                f"this session's speech service runs {self.engine}, which hears audio, not "
                "text: speak (voxshape teach --mic or --wav, the page's push-to-talk), type "
                "without --through-speech, or run the speech service with --engine mock"
            )
        else:
            what = (
                "this session's speech service runs the mock engine, which reads text, not "
                "audio: type your words, or run the speech service with --engine pocketsphinx"
            )
        return [
            TeacherNotice(
                teacher=teacher,
                robot=robot,
                utterance=new_message_id(),
                kind="not_recognized",
                meaning=None,
                text=f"not heard: {what}",
            )
        ]


class MockTranscriber:
    def __init__(self, mock: MockRecognizer, counters: Counter[str] | None = None) -> None:
        self.mock = mock
        self.counters: Counter[str] = counters if counters is not None else Counter()
        self._due: list[tuple[float, int, Recognized]] = []  # heap by due time
        self._order = itertools.count()

    def on_said(self, teacher: str, said: Said, now: float) -> list[Recognized]:
        """Schedules what the mock hears of `said`; returns the results already due."""
        if said.teacher != teacher:
            self.counters["said.wrong_teacher"] += 1
            return []
        heard_all = self.mock.hear(said.text, said.language, key=said.id)
        if not heard_all:  # dropped, or not in the vocabulary: rejected after the latency
            notice = not_recognized(said.teacher, said.robot, self.mock.engine)
            due = now + self.mock.settings.latency_s
            heapq.heappush(self._due, (due, next(self._order), notice))
        for index, heard in enumerate(heard_all):
            utterance = Utterance(
                id=heard_id(said.id, index),
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

    def on_tick(self, now: float) -> list[Recognized]:
        out = []
        while self._due and self._due[0][0] <= now:
            due, _, result = heapq.heappop(self._due)
            out.append(_recognized_at(result, due))
        return out

    def close(self, now: float) -> list[Recognized]:
        """Everything still pending, at once (the service is stopping)."""
        out = [_recognized_at(u, max(now, due)) for due, _, u in sorted(self._due)]
        self._due.clear()
        return out


def heard_id(said_id: str, index: int) -> str:
    """The id of the `index`-th utterance heard in a said text, derived from the text's id: a
    restarted speech service that hears again what a teacher's kept output recovers gives it
    the id it had, so the arbiter drops the copy instead of crediting the word twice."""
    return hashlib.blake2b(f"{said_id}|{index}".encode(), digest_size=16).hexdigest()


def _recognized_at(result: Recognized, when: float) -> Recognized:
    return replace(result, recognized_at=when) if isinstance(result, Utterance) else result

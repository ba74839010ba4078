"""The web page's gateway, pure: bus messages -> browser JSON, browser JSON and audio frames ->
protocol messages, and what each browser's teacher is shown (no zenoh, no aiohttp).

The WebSocket protocol is docs/web.md's. In short: a browser logs in, probes the gateway's
clock, types words ("say") and talks (push-to-talk: "talk" start, binary audio frames, "talk"
stop); it is sent a welcome (map, vocabulary, robots), the robots' observations (at most
`OBS_HZ` a second per robot, the latest winning), episodes, feedback, its teaching statistics,
the learning curve, one notice line per utterance (the very line `voxshape teach` shows), and
the robots' questions ("which way?") with who answered them.
"""

from __future__ import annotations

import json
import math
import struct
import tomllib
from collections import deque
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from protocol import (
    AudioChunk,
    CreditedFeedback,
    EpisodeEvent,
    HelpAnswer,
    HelpRequest,
    Message,
    Observation,
    Placed,
    ProtocolError,
    TeacherNotice,
    TeachingStats,
    Utterance,
    Vocabulary,
    check_id,
    encode,
)
from protocol.messages import MAX_CHUNK_BYTES, SAMPLE_RATE
from protocol.vocabulary import LANGUAGES
from services.runtime.limits import Throttle, TokenBucket
from services.teacher.board import Board, Shown
from services.teacher.sources import new_stream_id, typed
from services.world.maps import Box, Map

OBS_HZ = 10.0  # observations forwarded per robot and second, at most ...
OBS_AT_ONCE = 2.0  # ... and at once (a late frame and the next one)
MAX_TEXT_BYTES = 4 * 1024  # a JSON frame from a browser
MAX_BINARY_BYTES = 64 * 1024  # an audio frame from a browser (2 s of audio)
MAX_MESSAGES_PER_S = 50  # frames of one socket, text and binary together
AUDIO_HEADER = struct.Struct("<d")  # capture time of the first sample, browser ms
CURVE_KEPT = 1000  # ended episodes the welcome replays to a page that joins late
ONSET_TRUST_S = 10.0  # a browser time converted further than this from now is not believed
TRUSTED_RTT_MS = 1000.0  # a reported clock offset may sit this far below the one-way bound
AUDIO_BURST_S = 3.0  # audio seconds a teacher may send ahead of real time
LASER_FOV = math.pi  # the simulated robot's laser spans this, centred ahead (services/sim)
QUESTION_EVERY_S = 1.0  # a robot's questions (and answers) forwarded at most this often
QUESTIONS_PER_S = 5.0  # ... and all robots' together (a burst of QUESTIONS_BURST)
QUESTIONS_BURST = 10.0
QUESTION_OPEN_S = 10.0  # a page that joins this soon after an unanswered question is shown it
MAX_OPEN_QUESTIONS = 64  # open questions remembered for pages that join (the oldest forgotten)


class BrowserError(ValueError):
    """Something a browser sent that cannot be used; the text is sent back as an "error"."""


def now_ms(now_s: float) -> float:
    return round(now_s * 1000.0, 3)


# -- the session, as the page draws it -----------------------------------------------------


def map_json(m: Map) -> dict[str, Any]:
    """The map as the page draws it: walls as centre-line segments [x0, y0, x1, y1] (the border
    included), obstacles as boxes (centre, size, angle in radians, corners) and cylinders."""
    w, h = m.width, m.height
    walls = [[0.0, 0.0, w, 0.0], [w, 0.0, w, h], [w, h, 0.0, h], [0.0, h, 0.0, 0.0]]
    thickness = 0.1
    try:  # the extra walls are in the file as written; the Map holds them as boxes
        data = tomllib.loads(Path(m.source).read_text(encoding="utf-8"))
        walls += [[float(v) for v in wall] for wall in data.get("walls", [])]
        thickness = float(data.get("wall_thickness", thickness))
    except (OSError, tomllib.TOMLDecodeError):
        data = {}
    obstacles = []
    for shape in m.shapes[4 + len(data.get("walls", [])) :]:  # after the border and walls
        if isinstance(shape, Box):
            obstacles.append(
                {
                    "kind": "box",
                    "x": shape.x,
                    "y": shape.y,
                    "width": shape.width,
                    "depth": shape.depth,
                    "angle": shape.angle,
                    "corners": [list(c) for c in shape.corners()],
                }
            )
        else:
            obstacles.append({"kind": "cylinder", "x": shape.x, "y": shape.y, "r": shape.radius})
    return {
        "name": m.name,
        "width": w,
        "height": h,
        "wall_thickness": thickness,
        "walls": walls,
        "obstacles": obstacles,
        "goal": {"x": m.goal_x, "y": m.goal_y, "radius": m.goal_radius},
        "start": {
            "x": m.start.x,
            "y": m.start.y,
            "theta": m.start.theta,
            "jitter": [m.start_jitter.x, m.start_jitter.y, m.start_jitter.theta],
        },
    }


def vocabulary_json(vocabulary: Vocabulary) -> dict[str, list[dict[str, Any]]]:
    """Per language, every phrase with its meaning (the page's word buttons)."""
    out: dict[str, list[dict[str, Any]]] = {language: [] for language in LANGUAGES}
    for meaning in vocabulary.meanings.values():
        for language, phrases in meaning.phrases.items():
            out.setdefault(language, []).extend(
                {
                    "phrase": phrase,
                    "meaning": meaning.name,
                    "kind": meaning.kind,
                    "reward": meaning.reward,
                    "action": meaning.action,
                }
                for phrase in phrases
            )
    return out


@dataclass(frozen=True)
class SessionView:
    """What every page is told on joining, besides the robots (which change)."""

    session: str
    secured: bool
    language: str
    vocabulary: dict[str, list[dict[str, Any]]]
    map: dict[str, Any] | None
    viewer: str | None


# -- the robots: one stream for every page -------------------------------------------------

_BOARD = Board()  # stateless for episodes and feedback: the terminal client's fields


def obs_json(obs: Observation, at_s: float) -> dict[str, Any]:
    angles = [-LASER_FOV / 2, LASER_FOV / 2]
    if obs.laser:  # beams sit at the centres of equal slices of the field of view
        half = LASER_FOV / len(obs.laser) / 2
        angles = [-LASER_FOV / 2 + half, LASER_FOV / 2 - half]
    return {
        "type": "obs",
        "robot": obs.robot,
        "episode": obs.episode,
        "step": obs.step,
        "episode_step": obs.episode_step,
        "x": round(obs.x, 4),
        "y": round(obs.y, 4),
        "theta": round(obs.theta, 4),
        "laser": [round(r, 3) for r in obs.laser],
        "laser_angles": angles,
        "goal_distance": round(obs.goal_distance, 3),
        "reward": obs.reward,
        "outcome": obs.outcome,
        "collided": obs.collided,
        "stamp": now_ms(at_s),
        "wall_time": now_ms(obs.wall_time),
    }


def episode_json(event: EpisodeEvent) -> dict[str, Any]:
    return {"type": "episode", **_BOARD.episode(event)[0].data}


def feedback_json(feedback: CreditedFeedback) -> dict[str, Any]:
    return {"type": "feedback", **_BOARD.feedback(feedback)[0].data}


def question_json(question: HelpRequest, at_s: float) -> dict[str, Any]:
    """A robot's question; `text` is the terminal's line without its hint."""
    data = _BOARD.question(question)[0].data
    text = data.pop("message")
    return {"type": "question", **data, "text": text, "stamp": now_ms(at_s)}


def answer_json(answer: HelpAnswer) -> dict[str, Any]:
    """Who answered a robot's question, with what: `text` "answered by ana: left"."""
    data = _BOARD.answer(answer)[0].data
    text = data.pop("message")
    return {"type": "answer", **data, "text": text}


def stats_json(stats: TeachingStats, teacher: str) -> dict[str, Any]:
    """A robot's teaching statistics as one teacher sees them: its own and the count."""
    own = next((asdict(t) for t in stats.teachers if t.teacher == teacher), None)
    return {
        "type": "stats",
        "robot": stats.robot,
        "episode": stats.episode,
        "final": stats.final,
        "interventions": stats.interventions,
        "teacher": own,
        "teachers": len(stats.teachers),
    }


class Robots:
    """The robots of the session as the pages see them: which exist, their observations
    thinned to `hz` a second each (a token bucket per robot, 2 at once: at the simulator's
    own 10 Hz none waits; faster, the latest wins, sent when a token comes), and the learning
    curve (an ended episode's point once the arbiter's count of it is final)."""

    def __init__(self, hz: float = OBS_HZ) -> None:
        self.hz = hz
        self.seen: list[str] = []
        self._slots: dict[str, TokenBucket] = {}
        self._pending: dict[str, Observation] = {}
        self._ended: dict[tuple[str, int], EpisodeEvent] = {}
        self.curve: deque[dict[str, Any]] = deque(maxlen=CURVE_KEPT)
        self._asked: dict[str, tuple[dict[str, Any], float]] = {}  # robot -> open question
        self._per_robot = Throttle(QUESTION_EVERY_S)
        self._all = TokenBucket(QUESTIONS_PER_S, QUESTIONS_BURST)

    def _see(self, robot: str) -> None:
        if robot not in self.seen:
            self.seen.append(robot)

    def observation(self, obs: Observation, now: float) -> list[dict[str, Any]]:
        """The observation to forward now, if its robot's slot has come; else it waits."""
        self._see(obs.robot)
        self._pending[obs.robot] = obs
        return self.due(now)

    def due(self, now: float) -> list[dict[str, Any]]:
        """Waiting observations whose slot has come (call it a few times per period)."""
        out = []
        for robot, obs in list(self._pending.items()):
            slots = self._slots.get(robot)
            if slots is None:
                slots = self._slots[robot] = TokenBucket(self.hz, OBS_AT_ONCE, now)
            if slots.take(now):
                del self._pending[robot]
                out.append(obs_json(obs, now))
        return out

    def episode(self, event: EpisodeEvent) -> list[dict[str, Any]]:
        self._see(event.robot)
        if event.kind != "start":
            self._ended[(event.robot, event.episode)] = event
            while len(self._ended) > CURVE_KEPT:
                self._ended.pop(next(iter(self._ended)))
        return [episode_json(event)]

    def teaching(self, stats: TeachingStats) -> list[dict[str, Any]]:
        """The curve's point of an episode whose interventions are final."""
        ended = self._ended.pop((stats.robot, stats.episode), None) if stats.final else None
        if ended is None:
            return []
        point = {
            "type": "curve",
            "robot": stats.robot,
            "episode": stats.episode,
            "kind": ended.kind,
            "return": ended.env_return,
            "steps": ended.episode_steps,
            "interventions": stats.interventions,
        }
        self.curve.append(point)
        return [point]

    def _bounded(self, kind: str, robot: str, now: float) -> bool:
        """Whether a question (or answer) goes out: one a robot per QUESTION_EVERY_S, and
        QUESTIONS_PER_S of all robots; the excess is dropped."""
        return self._per_robot.due((kind, robot), now) and self._all.take(now)

    def question(
        self, question: HelpRequest, now: float, key_robot: str | None = None
    ) -> list[dict[str, Any]]:
        """A robot's question for every page (none claiming another robot than its key's,
        `key_robot`); remembered for pages that join while it is open."""
        if key_robot not in (None, question.robot):
            return []
        if not self._bounded("question", question.robot, now):
            return []
        item = question_json(question, now)
        self._asked.pop(question.robot, None)
        self._asked[question.robot] = (item, now)
        for robot, (_, at) in list(self._asked.items()):
            if now - at >= QUESTION_OPEN_S or len(self._asked) > MAX_OPEN_QUESTIONS:
                del self._asked[robot]  # oldest first
        return [item]

    def answer(self, answer: HelpAnswer, now: float) -> list[dict[str, Any]]:
        """Who answered a robot's question: for every page; the question is no longer open."""
        if not self._bounded("answer", answer.robot, now):
            return []
        asked = self._asked.get(answer.robot)
        if asked is not None and asked[0]["question"] == answer.question:
            del self._asked[answer.robot]
        return [answer_json(answer)]

    def open_questions(self, now: float) -> list[dict[str, Any]]:
        """Questions asked within QUESTION_OPEN_S that nobody answered, oldest first."""
        return [item for item, at in self._asked.values() if 0 <= now - at < QUESTION_OPEN_S]

    def welcome(self, view: SessionView, teacher: str, now: float) -> dict[str, Any]:
        return {
            "type": "welcome",
            "session": view.session,
            "teacher": teacher,
            "secured": view.secured,
            "robots": list(self.seen),
            "language": view.language,
            "vocabulary": view.vocabulary,
            "map": view.map,
            "viewer": view.viewer,
            "curve": list(self.curve),
            "questions": self.open_questions(now),
        }


# -- one browser -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Login:
    teacher: str
    user: str | None
    password: str | None


def parse_login(data: dict[str, Any], secured: bool) -> Login:
    """The first message of a socket; BrowserError says why it cannot log in. On a secured
    session the teacher id is the user name (the only one its router lets it speak as)."""
    if data.get("type") != "login":
        raise BrowserError('log in first: the first message must be {"type": "login", ...}')
    user, password = data.get("user") or None, data.get("password") or None
    if secured:
        if not (isinstance(user, str) and isinstance(password, str)):
            raise BrowserError("this session is secured: log in with your user name and password")
        teacher = user
    else:
        teacher = data.get("teacher") or user
        user = password = None
    try:
        return Login(check_id(teacher, "teacher"), user, password)
    except ProtocolError as e:
        raise BrowserError(f"not a usable teacher id: {e.problem}") from None


class Clock:
    """A browser's clock against the gateway's. Each probe's t0 (browser ms) and arrival t1
    (gateway ms) bound the offset from above: t1 - t0 = offset + the trip, so the smallest
    such difference is the best estimate the gateway can make alone. A browser that measured
    round trips itself reports its best (offset_ms, rtt_ms) in its probes, as a teacher's
    ClockProbe does on the bus; the lowest round trip reported wins over the one-way bound."""

    def __init__(self) -> None:
        self.one_way: float | None = None  # min(t1 - t0), ms
        self.reported: tuple[float, float] | None = None  # (offset_ms, rtt_ms)

    @property
    def offset_ms(self) -> float | None:
        """Gateway clock minus browser clock (ms); None before any probe."""
        return self.reported[0] if self.reported else self.one_way

    @property
    def rtt_ms(self) -> float | None:
        return self.reported[1] if self.reported else None

    def probe(self, data: dict[str, Any], now_s: float) -> dict[str, Any]:
        t0, t1 = _number(data, "t0"), now_ms(now_s)
        if self.one_way is None or t1 - t0 < self.one_way:
            self.one_way = t1 - t0
        offset, rtt = data.get("offset_ms"), data.get("rtt_ms")
        if offset is not None or rtt is not None:
            offset, rtt = _number(data, "offset_ms"), _number(data, "rtt_ms")
            if not 0 <= rtt <= 60_000:
                raise BrowserError(f"clock: rtt_ms {rtt:g} is not within 0-60000")
            # t1 - t0 = offset + the way here, which is within [0, rtt]: a reported offset
            # outside what the gateway's own bound allows is moved to its edge
            lowest = self.one_way - min(rtt, TRUSTED_RTT_MS)
            offset = min(self.one_way, max(lowest, offset))
            if self.reported is None or rtt <= self.reported[1]:
                self.reported = (offset, rtt)
        return {
            "type": "clock",
            "t0": t0,
            "t1": t1,
            "offset_ms": self.offset_ms,
            "rtt_ms": self.rtt_ms,
        }

    def to_gateway(self, browser_ms: float, now_s: float) -> float:
        """A browser time as gateway seconds; the arrival time when it cannot be believed
        (no probe yet, or further than ONSET_TRUST_S from now)."""
        if self.offset_ms is None:
            return now_s
        at = (browser_ms + self.offset_ms) / 1000.0
        return at if abs(at - now_s) <= ONSET_TRUST_S else now_s


def _number(data: dict[str, Any], name: str) -> float:
    value = data.get(name)
    try:
        number = float(value) if isinstance(value, int | float) else math.nan
    except OverflowError:  # an integer of hundreds of digits
        number = math.nan
    if isinstance(value, bool) or not math.isfinite(number):
        raise BrowserError(f"{data.get('type')!s:.20}: {name} must be a finite number")
    return number


def parse_frame(text: str) -> dict[str, Any]:
    """A browser's JSON frame, at most MAX_TEXT_BYTES; BrowserError if it is not usable."""
    if len(text) > MAX_TEXT_BYTES or len(text.encode()) > MAX_TEXT_BYTES:
        raise BrowserError(f"a text message is over {MAX_TEXT_BYTES} bytes")
    try:
        data = json.loads(text)
    except (ValueError, RecursionError):
        raise BrowserError("not JSON (or nested too deep)") from None
    if not isinstance(data, dict):
        raise BrowserError('a message is a JSON object with a "type"')
    return data


@dataclass
class Talk:
    """One push-to-talk press: one audio stream."""

    robot: str
    stream: str = field(default_factory=lambda: new_stream_id("web"))
    seq: int = 0
    end: float | None = None  # gateway seconds at the end of the audio so far


@dataclass
class Outcome:
    """What a browser's frame gives: messages for the bus, JSON for the browser."""

    messages: list[Message] = field(default_factory=list)
    replies: list[dict[str, Any]] = field(default_factory=list)


class Teaching:
    """One logged-in browser: its teacher, watched robot, clock, push-to-talk stream, and its
    Board (services/teacher/board.py), so its notice lines are the terminal client's."""

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
        self.clock = Clock()
        self.talk: Talk | None = None

    def _robot(self, data: dict[str, Any]) -> str:
        robot = data.get("robot") or self.robot or (self.robots.seen or [None])[0]
        if robot is None:
            raise BrowserError(f"{data.get('type')}: no robot is running yet")
        try:
            return check_id(robot, "robot")
        except ProtocolError as e:
            raise BrowserError(f"{data.get('type')}: {e.problem}") from None

    def text(self, data: dict[str, Any], now_s: float, now_mono: float) -> Outcome:
        """A JSON message of the browser; BrowserError if it cannot be used."""
        kind = data.get("type")
        if kind == "clock":
            return Outcome(replies=[self.clock.probe(data, now_s)])
        if kind == "watch":
            self.robot = self._robot(data)
            return Outcome()
        if kind == "say":
            return self._say(data, now_s, now_mono)
        if kind == "talk":
            return self._talk(data, now_s)
        if kind == "placed":  # a real robot is back at its start (voxshape ros2 waits)
            return Outcome(
                messages=[_checked(Placed(teacher=self.teacher, robot=self._robot(data)))]
            )
        if kind == "login":
            raise BrowserError("already logged in")
        raise BrowserError(f"unknown message type {kind!r}: clock, watch, say, talk, placed")

    def _say(self, data: dict[str, Any], now_s: float, now_mono: float) -> Outcome:
        text = data.get("text")
        if not isinstance(text, str) or not text.strip():
            raise BrowserError("say: text must be a non-empty string")
        if len(text) > 500:
            raise BrowserError("say: text is longer than 500 characters")
        language = data.get("language") or self.language
        if language not in LANGUAGES:
            raise BrowserError(f"say: language must be one of {', '.join(LANGUAGES)}")
        onset = data.get("onset")
        at = now_s if onset is None else self.clock.to_gateway(_number(data, "onset"), now_s)
        utterance = typed(text.strip(), self.teacher, self._robot(data), language, at, False)
        assert isinstance(utterance, Utterance)
        utterance = _checked(replace(utterance, recognized_at=now_s))
        self.board.sent(utterance, now_mono)
        return Outcome(messages=[utterance])

    def _talk(self, data: dict[str, Any], now_s: float) -> Outcome:
        state = data.get("state")
        if state == "start":
            out = self._stop(now_s)  # a press without its release ends the earlier stream
            self.talk = Talk(self._robot(data))
            return out
        if state == "stop":
            return self._stop(now_s)
        raise BrowserError("talk: state must be start or stop")

    def _stop(self, now_s: float) -> Outcome:
        talk, self.talk = self.talk, None
        if talk is None:
            return Outcome()
        return Outcome(messages=[self._chunk(talk, b"", talk.end or now_s, final=True)])

    def audio(self, frame: bytes, now_s: float) -> Outcome:
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
        return Outcome(messages=messages)

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

    def recognized(self, utterance: Utterance, now_mono: float) -> None:
        """This teacher's utterance as the bus carried it (speech's, or the echo of a typed
        one): its notice is awaited."""
        self.board.recognized(utterance, now_mono)

    def tick(self, now_mono: float) -> list[dict[str, Any]]:
        return [notice_json(s) for s in self.board.tick(now_mono) if s.event == "no_answer"]

    def stats(self, stats: TeachingStats) -> dict[str, Any]:
        return stats_json(stats, self.teacher)


def notice_json(shown: Shown) -> dict[str, Any]:
    """A Board line (notice or no answer) as the page shows it: `text` is the terminal's."""
    data = shown.data
    return {
        "type": "notice",
        "robot": data.get("robot"),
        "utterance": data.get("utterance"),
        "kind": data["kind"] if shown.event == "notice" else "no_answer",
        "meaning": data.get("meaning"),
        "text": shown.text,
        "heard": data.get("text"),
        "late": bool(data.get("late", False)),
    }


def _checked(message: Message) -> Any:
    """The message if the codec would send it; BrowserError naming the field if not."""
    try:
        encode(message)
    except ProtocolError as e:
        raise BrowserError(f"{e.field}: {e.problem}") from None
    return message

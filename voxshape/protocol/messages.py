"""Every message that travels on the voxshape bus, with the bounds of each field.

Each message carries the envelope fields of `Message` (a unique `id` for dedupe, the `sender`
node and the sender's clock `sent_at`); the codec adds the schema version and type tag.
Times are seconds: `*_time`/`sent_at`/`onset`/`end` are Unix wall-clock seconds on the clock
of whoever produced them, `sim_time` is simulated seconds since the simulator started.
Angles are radians, distances metres, velocities m/s and rad/s.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field
from typing import Annotated, ClassVar, Literal

from voxshape.protocol.schema import Match, ProtocolError, Range, Size

# Ids of sessions, robots, teachers and nodes become key-expression chunks: no '/', '*', '$',
# '?', '#', spaces or leading '@' (zenoh reserves them).
ID_PATTERN = r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}"
ID_HINT = "use 1-64 of A-Z a-z 0-9 _ - . starting with a letter or digit"

Id = Annotated[str, Match(ID_PATTERN, ID_HINT)]
MessageId = Annotated[str, Match(r"[0-9a-f]{32}", "32 lowercase hex digits (16 random bytes)")]
Count = Annotated[int, Range(0, 2**31 - 1)]
WallTime = Annotated[float, Range(0.0, 1e11)]
SimTime = Annotated[float, Range(0.0, 1e9)]
Metres = Annotated[float, Range(-1e4, 1e4)]
Heading = Annotated[float, Range(-math.pi, math.pi)]
Speed = Annotated[float, Range(-10.0, 10.0)]
TurnRate = Annotated[float, Range(-20.0, 20.0)]
Reward = Annotated[float, Range(-1e6, 1e6)]
Range01 = Annotated[float, Range(0.0, 1.0)]
Text = Annotated[str, Size(max=500)]
Name = Annotated[str, Size(min=1, max=32)]
# A vocabulary's language: an ISO 639 code. Any a vocabulary file holds may travel (en, es, ko...).
LANGUAGE_PATTERN = r"[a-z]{2,3}"
Language = Annotated[str, Match(LANGUAGE_PATTERN, "an ISO 639 code: 2-3 lowercase letters (en)")]

# The discrete actions of the robot; an action's id on the wire is its index here.
ACTION_NAMES: tuple[str, ...] = ("stop", "forward", "back", "left", "right")
ActionName = Literal["stop", "forward", "back", "left", "right"]
ActionId = Annotated[int, Range(0, len(ACTION_NAMES) - 1)]

SAMPLE_RATE = 16_000
MAX_CHUNK_BYTES = 2 * SAMPLE_RATE  # one second of 16-bit mono audio
MIN_CONFIDENCE = 0.5  # the arbiter's default: an utterance heard with less is not taken


def new_message_id() -> str:
    """128 random bits, as uuid4 has (without its version bits), 4x cheaper to make."""
    return os.urandom(16).hex()


@dataclass(frozen=True, kw_only=True)
class Message:
    """Envelope fields every message has. The bus node fills `sender` and `sent_at`."""

    TYPE: ClassVar[str]

    id: MessageId = field(default_factory=new_message_id)
    sender: Id = "unset"
    sent_at: WallTime = field(default_factory=time.time)

    def check(self) -> None:
        """Cross-field rules; raises ProtocolError. Single-field bounds live in the types."""


@dataclass(frozen=True, kw_only=True)
class Observation(Message):
    """What a robot senses after control step `step` (simulator -> *), 10 Hz of sim time."""

    TYPE: ClassVar[str] = "observation"

    robot: Id
    episode: Count
    step: Count  # global step index of this robot, monotonic across episodes
    episode_step: Count
    sim_time: SimTime
    wall_time: WallTime
    x: Metres
    y: Metres
    theta: Heading
    v: Speed
    omega: TurnRate
    laser: Annotated[tuple[Annotated[float, Range(0.0, 100.0)], ...], Size(max=1081)]
    sonar: Annotated[tuple[Annotated[float, Range(0.0, 100.0)], ...], Size(max=32)]
    reward: Reward  # R_RL of the transition that led here
    goal_distance: Annotated[float, Range(0.0, 1e4)]  # straight line to the goal's centre
    goal_bearing: Heading  # to the goal's centre, from the heading (+ = to the left)
    # How the episode stands after this step. Not "running": the episode ended here, no
    # action is expected for this step, and the next observation starts a new episode.
    outcome: Literal["running", "goal", "collision", "timeout"]
    collided: bool  # touched something during the step (also when collisions do not end it)


@dataclass(frozen=True, kw_only=True)
class Action(Message):
    """The action for observation `step` (learner or teacher -> simulator).

    A discrete action id, a continuous (v, omega), or both (the blend the learner sent and
    the discrete action it is credited to).
    """

    TYPE: ClassVar[str] = "action"

    robot: Id
    episode: Count
    step: Count
    discrete: ActionId | None
    v: Speed | None
    omega: TurnRate | None
    chooser: Literal["policy", "teacher"]

    def check(self) -> None:
        if (self.v is None) != (self.omega is None):
            raise ProtocolError("Action.v", "v and omega go together: give both or neither")
        if self.discrete is None and self.v is None:
            raise ProtocolError("Action.discrete", "give a discrete id, (v, omega), or both")


@dataclass(frozen=True, kw_only=True)
class EpisodeEvent(Message):
    """An episode starting or ending (simulator -> *)."""

    TYPE: ClassVar[str] = "episode"

    robot: Id
    episode: Count
    step: Count
    kind: Literal["start", "goal", "collision", "timeout"]
    episode_steps: Count
    sim_time: SimTime
    wall_time: WallTime
    env_return: Reward  # sum of R_RL over the episode so far


@dataclass(frozen=True, kw_only=True)
class AudioChunk(Message):
    """20-100 ms of a teacher's microphone or file (teacher client -> speech)."""

    TYPE: ClassVar[str] = "audio"

    teacher: Id
    robot: Id  # the robot this teacher is speaking to
    stream: Id  # one per microphone/file stream; `seq` counts chunks within it
    seq: Count
    sample_rate: Literal[16000]
    pcm: Annotated[bytes, Size(max=MAX_CHUNK_BYTES)]  # int16 little-endian mono
    capture_time: WallTime  # teacher clock at the first sample
    final: bool  # the stream ends with this chunk

    def check(self) -> None:
        if len(self.pcm) % 2:
            raise ProtocolError("AudioChunk.pcm", "odd byte count: int16 samples are 2 bytes")


@dataclass(frozen=True, kw_only=True)
class Alternative:
    text: Text
    confidence: Range01


@dataclass(frozen=True, kw_only=True)
class Utterance(Message):
    """What a teacher said (speech service or typing teacher -> arbiter)."""

    TYPE: ClassVar[str] = "utterance"

    teacher: Id
    robot: Id
    text: Text
    confidence: Range01
    onset: WallTime  # teacher clock: the teacher started speaking (or typing)
    end: WallTime  # teacher clock
    recognized_at: WallTime  # recognizer's clock
    engine: Name  # "vosk", "pocketsphinx", "mock", "typed", ...
    language: Language
    alternatives: Annotated[tuple[Alternative, ...], Size(max=10)]

    def check(self) -> None:
        if self.end < self.onset:
            raise ProtocolError("Utterance.end", f"end {self.end} is before onset {self.onset}")


@dataclass(frozen=True, kw_only=True)
class Said(Message):
    """What a teacher said, as text, for the mock speech engine (a simulated teacher or
    `voxshape teach --through-speech` -> `voxshape speech --engine mock`). The mock mishears
    it as configured and publishes the Utterance; real engines take AudioChunk instead."""

    TYPE: ClassVar[str] = "said"

    teacher: Id
    robot: Id
    text: Text
    language: Language
    onset: WallTime  # teacher clock: the teacher started speaking
    end: WallTime  # teacher clock

    def check(self) -> None:
        if self.end < self.onset:
            raise ProtocolError("Said.end", f"end {self.end} is before onset {self.onset}")


@dataclass(frozen=True, kw_only=True)
class Credit:
    step: Count
    weight: Range01


@dataclass(frozen=True, kw_only=True)
class CreditedFeedback(Message):
    """A teacher reward or command, credited to the steps it was about (arbiter -> learner)."""

    TYPE: ClassVar[str] = "feedback"

    robot: Id
    kind: Literal["reward", "command"]
    reward: Reward | None  # the teachers' merged f; the learner's g bounds it
    command: ActionName | None
    credits: Annotated[tuple[Credit, ...], Size(min=1, max=256)]
    sources: Annotated[tuple[MessageId, ...], Size(min=1, max=64)]  # utterance ids
    teachers: Annotated[tuple[Id, ...], Size(min=1, max=64)]
    question: MessageId | None = None  # a command answering a HelpRequest: the question's id

    def check(self) -> None:
        if self.kind == "reward" and (self.reward is None or self.command is not None):
            raise ProtocolError("CreditedFeedback.reward", "a reward needs reward and no command")
        if self.kind == "command" and (self.command is None or self.reward is not None):
            raise ProtocolError("CreditedFeedback.command", "a command needs command, no reward")
        if self.question is not None and self.kind != "command":
            raise ProtocolError("CreditedFeedback.question", "only a command answers a question")
        total = sum(c.weight for c in self.credits)
        if total > 1.0 + 1e-6:
            raise ProtocolError("CreditedFeedback.credits", f"weights sum to {total:g} > 1")


@dataclass(frozen=True, kw_only=True)
class LearningSummary(Message):
    """The learner's view after a step (learner -> logger)."""

    TYPE: ClassVar[str] = "learning"

    robot: Id
    episode: Count
    step: Count
    state: Count  # index of the current state
    states: Count  # number of states created so far
    q_values: Annotated[tuple[Reward, ...], Size(max=len(ACTION_NAMES))]
    td_error: Reward
    epsilon: Range01
    reward: Reward  # R_RL of the step
    episode_return: Reward  # the sum of r the learner used this episode (R_RL + R_U)


ClockOffset = Annotated[float, Range(-1e9, 1e9)]  # seconds, one clock minus another
RoundTrip = Annotated[float, Range(0.0, 60.0)]  # seconds


@dataclass(frozen=True, kw_only=True)
class ClockProbe(Message):
    """A teacher asking the arbiter's clock, NTP style (teacher -> arbiter). `t0` is when it
    left, on the teacher's clock. It also reports the teacher's best estimate from earlier
    replies (None on a first probe): offset = arbiter clock - teacher clock, and its round trip.
    The arbiter corrects the teacher's utterance times with the latest estimate reported."""

    TYPE: ClassVar[str] = "clock_probe"

    teacher: Id
    t0: WallTime  # teacher clock
    offset: ClockOffset | None
    rtt: RoundTrip | None

    def check(self) -> None:
        if (self.offset is None) != (self.rtt is None):
            raise ProtocolError("ClockProbe.offset", "offset and rtt go together: both or neither")


@dataclass(frozen=True, kw_only=True)
class ClockReply(Message):
    """The arbiter's answer to a ClockProbe (arbiter -> teacher). With t3, when it arrives on
    the teacher's clock: offset = ((t1 - t0) + (t2 - t3)) / 2, rtt = (t3 - t0) - (t2 - t1)."""

    TYPE: ClassVar[str] = "clock_reply"

    teacher: Id
    probe: MessageId  # the ClockProbe's id
    t0: WallTime  # teacher clock, echoed from the probe
    t1: WallTime  # arbiter clock: the probe arrived
    t2: WallTime  # arbiter clock: this reply left

    def check(self) -> None:
        if self.t2 < self.t1:
            raise ProtocolError("ClockReply.t2", f"t2 {self.t2} is before t1 {self.t1}")


NoticeKind = Literal[
    "understood",
    "low_confidence",
    "not_understood",
    "rate_limited",
    "unknown_robot",
    "too_late",
    "not_recognized",  # from the speech service: speech heard, no phrase of the vocabulary
]


@dataclass(frozen=True, kw_only=True)
class TeacherNotice(Message):
    """What the arbiter made of one utterance, for the teacher client to show (arbiter ->
    teacher): understood, or why it was ignored (rate-limited ones at most once a second).
    The speech service sends "not_recognized" for speech it rejected (`utterance` is then the
    id of that rejection: no Utterance exists)."""

    TYPE: ClassVar[str] = "notice"

    teacher: Id
    robot: Id
    utterance: MessageId
    kind: NoticeKind
    meaning: Name | None  # the vocabulary meaning, when understood
    text: Text  # a sentence for people, e.g. "not understood, please repeat"


# A question's lifetime: the first command said within it answers it (the arbiter), and the
# robot does not ask again while it is open (the learner); seconds of the teacher's clock.
QUESTION_OPEN_S = 6.0


@dataclass(frozen=True, kw_only=True)
class HelpRequest(Message):
    """The robot asks its teachers "which way?" (learner -> arbiter, teachers): why, and
    where it is. The first command said within QUESTION_OPEN_S answers it: the arbiter sends
    it as a command credited to `step` that names this request's id (`question`)."""

    TYPE: ClassVar[str] = "help"

    robot: Id
    episode: Count
    step: Count  # the observation it asked at: an answer is credited to it
    reason: Literal["stuck", "late", "unsure"]
    detail: Text  # for people, e.g. "stuck for 10 s"
    x: Metres
    y: Metres


@dataclass(frozen=True, kw_only=True)
class HelpAnswer(Message):
    """Who answered a robot's question, and with what (arbiter -> learner, teachers): the
    first understood word after it; the other teachers see it was answered."""

    TYPE: ClassVar[str] = "answer"

    robot: Id
    question: MessageId  # the HelpRequest's id
    step: Count  # the question's step
    teacher: Id
    meaning: Name  # the vocabulary meaning of the answer, e.g. "left"
    utterance: MessageId


@dataclass(frozen=True, kw_only=True)
class Placed(Message):
    """A teacher says a real robot stands at its start again (teacher -> voxshape ros2): the
    robot that waits between episodes (`voxshape ros2 --reset wait`) starts the next one."""

    TYPE: ClassVar[str] = "placed"

    teacher: Id
    robot: Id


@dataclass(frozen=True, kw_only=True)
class RobotLimits(Message):
    """How fast a robot may be driven (simulator or `voxshape ros2` -> learner): the learner
    scales its actions to fit, so that what it sends is never clipped."""

    TYPE: ClassVar[str] = "limits"

    robot: Id
    max_speed: Annotated[float, Range(0.001, 10.0)]  # m/s, forward and back
    max_turn: Annotated[float, Range(0.001, 20.0)]  # rad/s, either way


@dataclass(frozen=True, kw_only=True)
class TeacherStats:
    """One teacher's part in a robot's teaching (within TeachingStats)."""

    teacher: Id
    interventions: Count  # understood utterances about this episode
    utterances: Count  # utterances to this robot since the arbiter started
    understood: Count
    ignored: Count  # low confidence, not understood, rate limited, too late
    compared: Count  # pairs of its judgement and another teacher's about the same steps
    agreement: Range01 | None  # share of those with the same sign (None: none compared)
    delay: Annotated[float, Range(0.0, 60.0)]  # centre of the reaction-delay window (s)
    delay_width: Annotated[float, Range(0.0, 60.0)]  # its width (s)
    delay_learned: bool  # learnt from this teacher's own reactions, else configured
    clock_offset: ClockOffset | None  # arbiter clock - teacher clock (None: never synced)
    clock_rtt: RoundTrip | None


@dataclass(frozen=True, kw_only=True)
class TeachingStats(Message):
    """Interventions of one episode of a robot (the paper's Table 3) and each teacher's
    statistics (arbiter -> *). Sent as they change; `final` once the episode ended and late
    feedback had time to arrive."""

    TYPE: ClassVar[str] = "teaching"

    robot: Id
    episode: Count
    final: bool
    interventions: Count  # understood utterances about this episode, all teachers
    teachers: Annotated[tuple[TeacherStats, ...], Size(max=64)]


@dataclass(frozen=True, kw_only=True)
class Learnt(Message):
    """A robot has learnt its task, by the convergence rule (the demo -> teachers' pages):
    the episode it converged in, how many episodes and robot seconds it took. It goes on, an
    episode after another: a teacher may keep teaching it, or start another room."""

    TYPE: ClassVar[str] = "learnt"

    robot: Id
    episode: Count  # the episode it converged in
    episodes: Count  # how many it took, that one included
    robot_seconds: SimTime  # their robot time
    task: Text  # what it learnt, e.g. "task 1", "map office.toml (Office)"


MESSAGE_TYPES: dict[str, type[Message]] = {
    cls.TYPE: cls
    for cls in (
        Observation,
        Action,
        EpisodeEvent,
        AudioChunk,
        Utterance,
        Said,
        CreditedFeedback,
        LearningSummary,
        ClockProbe,
        ClockReply,
        TeacherNotice,
        TeachingStats,
        HelpRequest,
        HelpAnswer,
        Placed,
        RobotLimits,
        Learnt,
    )
}

"""`voxshape sim-teacher`: the simulated teacher on the bus, speaking through the normal path.

Inputs:  voxshape/<session>/robot/<robot>/obs              what it watches
         voxshape/<session>/teacher/<teacher>/notice       what the arbiter made of it (counted)
         voxshape/<session>/teacher/<teacher>/clock-reply  the clock exchange (a thread)
Outputs: voxshape/<session>/teacher/<teacher>/said     its words, for the mock speech engine
         voxshape/<session>/teacher/<teacher>/audio    or its words synthesized (--audio), for
                                                       pocketsphinx: recognition errors are real
         voxshape/<session>/teacher/<teacher>/clock    clock probes (services/runtime/clock.py)

It sends what a person's `voxshape teach` client sends, nothing more: the speech service hears
it, the arbiter credits it, the learner takes it.

Time: the teacher watches a display that shows each step when its observation arrives, and
reacts in the robot's time (its interval, reaction delay and speaking time are robot seconds,
`step x control period`). A word is sent once the step at the end of its speech is displayed,
with its onset and end at the display times of those steps, on the teacher's own clock. On a
paced simulator at real time this is a person; on a lockstep one it is a person watching the
robot fast-forwarded, who still reacts after as many steps as at normal speed (a real-time
reaction would land hundreds of steps late). It never says more than `--max-rate` things per
robot second (a person says at most 2-3 a second); the arbiter must be told it lives in robot
time (`voxshape arbiter --robot-time <teacher>`), or it refuses the fast-forwarded words as a
flood and credits them with a person's delays.
"""

from __future__ import annotations

import argparse
import heapq
import io
import math
import os
import random
import shutil
import subprocess
import time
import wave
from bisect import bisect_left
from collections import Counter, deque
from dataclasses import dataclass

import numpy as np

from protocol import (
    Message,
    Observation,
    Said,
    TeacherNotice,
    check_id,
    load_vocabulary,
    robot_key,
    teacher_key,
)
from protocol.messages import SAMPLE_RATE
from services.arbiter.hygiene import TokenBucket
from services.runtime import (
    ConfigError,
    Input,
    Node,
    add_bus_arguments,
    bus_config,
    fields,
)
from services.runtime.clock import ClockSync
from services.sim.maps import TASKS, load_map
from services.sim.task import SimConfig
from services.simteacher.teacher import (
    Confusion,
    FeedbackSchedule,
    Look,
    SimulatedTeacher,
    TeacherProfile,
    path_command,
)
from services.teacher.sources import wav_stream

COMMAND_EVERY_S = 0.5  # robot seconds between dictated commands (a command steers 5 steps)
DISPLAY_MEMORY = 4096  # steps whose display time is remembered
LEAD_S, TRAIL_S = 0.3, 0.5  # synthesized speech: silence before (onset at its end) and after
VOICE = "en-us"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    env = os.environ.get
    profile, schedule = TeacherProfile(), FeedbackSchedule()
    parser.add_argument("--robot", default=env("VOXSHAPE_ROBOT", "r1"), help="(VOXSHAPE_ROBOT)")
    parser.add_argument(
        "--teacher", default=env("VOXSHAPE_TEACHER", "simteacher"), help="(VOXSHAPE_TEACHER)"
    )
    parser.add_argument(
        "--task",
        default=env("VOXSHAPE_TASK", "1"),
        help=f"the simulator's map, for the true distance to the goal: task number "
        f"({', '.join(TASKS)}) or map file (VOXSHAPE_TASK)",
    )
    parser.add_argument(
        "--noise",
        type=float,
        default=0.0,
        help="share of its judgements it gets wrong (the opposite qualifier); recognition "
        "errors are the speech service's",
    )
    parser.add_argument(
        "--positive-bias",
        type=float,
        default=profile.positive_bias,
        help="share of scolding unsaid",
    )
    parser.add_argument(
        "--stuck-after",
        type=float,
        default=profile.stuck_after,
        help="robot seconds without progress after which each look is 'bad' (0: never)",
    )
    parser.add_argument(
        "--repeat-after",
        type=float,
        default=profile.repeat_after,
        help="robot seconds before it says the same judgement again while nothing changes "
        "(0: at every look)",
    )
    parser.add_argument(
        "--attentive",
        action="store_true",
        help="after an episode without the goal, or over twice the robot's best time, comment "
        "on everything again (else the schedule decides)",
    )
    parser.add_argument(
        "--delay", type=float, default=profile.delay, help="reaction delay, robot seconds"
    )
    parser.add_argument("--jitter", type=float, default=profile.jitter, help="its std dev")
    parser.add_argument(
        "--interval", type=float, default=profile.interval, help="robot seconds between looks"
    )
    parser.add_argument(
        "--always-for",
        type=int,
        default=schedule.permanent_episodes,
        help="feedback schedule: it comments on everything it judges for this many episodes...",
    )
    parser.add_argument(
        "--fade-over", type=int, default=schedule.fade_episodes, help="...then fades over these..."
    )
    parser.add_argument(
        "--sporadic",
        type=float,
        default=schedule.sporadic,
        help="...to commenting on this share",
    )
    parser.add_argument(
        "--traces",
        type=int,
        default=0,
        help="dictate the first N episodes it sees start: commands along the shortest path",
    )
    parser.add_argument(
        "--max-rate",
        type=float,
        default=3.0,
        help="utterances per robot second at most (the arbiter allows 4)",
    )
    parser.add_argument(
        "--audio",
        action="store_true",
        help="speak synthesized audio (espeak-ng and sox) to a pocketsphinx speech service "
        "instead of text to the mock engine",
    )
    parser.add_argument("--voice", default=VOICE, help="--audio: espeak-ng voice")
    parser.add_argument(
        "--clock-skew", type=float, default=0.0, help="its own clock runs this many seconds off"
    )
    parser.add_argument("--seed", type=int, default=None, help="(default: drawn, and logged)")


def profile_from(args: argparse.Namespace) -> TeacherProfile:
    try:
        return TeacherProfile(
            interval=args.interval,
            schedule=FeedbackSchedule(
                permanent_episodes=args.always_for,
                fade_episodes=args.fade_over,
                sporadic=args.sporadic,
            ),
            noise=args.noise,
            # Over the bus the speech service mishears: the teacher's own errors are slips.
            confusion=Confusion(wrong_qualifier=1.0, misheard=0.0),
            positive_bias=args.positive_bias,
            delay=args.delay,
            jitter=args.jitter,
            stuck_after=args.stuck_after,
            repeat_after=args.repeat_after,
            attentive=args.attentive,
        )
    except ValueError as e:
        raise ConfigError(f"sim-teacher: {e}") from None


@dataclass(frozen=True)
class Spoken:
    """Words to send: the text and when the teacher started and stopped saying it (own clock)."""

    text: str
    onset: float
    end: float
    kind: str  # "judgement" or "command"


class DisplayClock:
    """When each step of the robot was displayed, on the teacher's clock."""

    def __init__(self, memory: int = DISPLAY_MEMORY) -> None:
        self._robot: deque[float] = deque(maxlen=memory)
        self._shown: deque[float] = deque(maxlen=memory)

    def shown(self, robot_time: float, at: float) -> None:
        if self._robot and robot_time < self._robot[-1]:  # the simulator started over
            self._robot.clear()
            self._shown.clear()
        self._robot.append(robot_time)
        self._shown.append(at)

    def at(self, robot_time: float) -> float:
        """The display time of the first step at or after `robot_time` (the latest if none)."""
        i = bisect_left(self._robot, robot_time)
        return self._shown[min(i, len(self._shown) - 1)]


class BusTeacher:
    """The teacher between the bus and the core: observations and its own clock in, words to
    say out (pure: no bus). Dictates the first `traces` episodes it sees start, then judges."""

    def __init__(
        self,
        teacher: SimulatedTeacher,
        traces: int = 0,
        max_rate: float = 3.0,
        control_period: float = SimConfig.control_period,
        counters: Counter[str] | None = None,
    ) -> None:
        self.teacher = teacher
        self.traces = traces
        self.control_period = control_period
        self.counters: Counter[str] = Counter() if counters is None else counters
        self.display = DisplayClock()
        self.max_rate = max_rate
        self._bucket: TokenBucket | None = None
        self._pending: list[tuple[float, int, str, float]] = []  # (end, order, text, onset)
        self._order = 0
        self._started = 0  # episodes seen from their start
        self._episode: int | None = None  # the simulator's episode being watched
        self._dictating = False
        self._next_command = -math.inf

    def on_observation(self, obs: Observation, now: float) -> list[Spoken]:
        t = obs.step * self.control_period  # robot seconds
        self.display.shown(t, now)
        if obs.episode != self._episode:
            self._episode = obs.episode
            seen_start = obs.episode_step == 0
            self._started += seen_start
            self._dictating = seen_start and self._started <= self.traces
            self._next_command = -math.inf
        out: list[Spoken] = []
        if self._dictating:
            if obs.outcome == "running" and t >= self._next_command - 1e-9:
                self._next_command = t + COMMAND_EVERY_S
                text = self.teacher.phrase(path_command(self.teacher.map, obs.x, obs.y, obs.theta))
                out.append(Spoken(text, now, now, "command"))
        else:
            episode = max(0, self._started - self.traces - 1)  # of the episodes it judges
            look = Look(t, episode, obs.x, obs.y, obs.collided, obs.outcome, obs.theta)
            for speech in self.teacher.watch(look):
                heapq.heappush(self._pending, (speech.end, self._order, speech.said, speech.onset))
                self._order += 1
        while self._pending and self._pending[0][0] <= t + 1e-9:
            end, _, text, onset = heapq.heappop(self._pending)
            out.append(Spoken(text, self.display.at(onset), self.display.at(end), "judgement"))
        return [s for s in out if self._may_say(s, t)]

    def _may_say(self, spoken: Spoken, t: float) -> bool:
        if self._bucket is None or t < self._bucket.updated:  # none yet, or a new simulator
            self._bucket = TokenBucket(self.max_rate, max(1.0, self.max_rate), t)
        if self._bucket.take(t):
            self.counters[f"said.{spoken.kind}"] += 1
            return True
        self.counters[f"unsaid.{spoken.kind}.too_fast"] += 1
        return False


class Voice:
    """Phrases synthesized by espeak-ng, as 16 kHz mono int16 samples with silence around."""

    def __init__(self, voice: str = VOICE) -> None:
        missing = [tool for tool in ("espeak-ng", "sox") if shutil.which(tool) is None]
        if missing:
            raise ConfigError(
                f"--audio needs {' and '.join(missing)} (Debian: apt-get install espeak-ng sox); "
                "without them, run the speech service's mock engine and leave out --audio"
            )
        self.voice = voice
        self._cache: dict[str, np.ndarray] = {}

    def __call__(self, text: str) -> np.ndarray:
        if text not in self._cache:
            self._cache[text] = synthesize(text, self.voice)
        return self._cache[text]


def synthesize(text: str, voice: str = VOICE) -> np.ndarray:
    """`text` spoken by espeak-ng, trimmed, normalized and padded (LEAD_S, TRAIL_S) by sox."""
    speech = _run(["espeak-ng", "-v", voice, "-s", "150", "--stdout", text])
    trim = ["silence", "1", "0.01", "0.1%", "reverse", "silence", "1", "0.01", "0.1%", "reverse"]
    fmt = ["-r", str(SAMPLE_RATE), "-c", "1", "-b", "16", "-e", "signed-integer"]
    pad = ["pad", f"{LEAD_S}", f"{TRAIL_S}"]
    wav = _run(
        ["sox", "-R", "-t", "wav", "-", *fmt, "-t", "wav", "-", *trim, "gain", "-n", "-3", *pad],
        speech,
    )
    with wave.open(io.BytesIO(wav)) as w:
        return np.frombuffer(w.readframes(w.getnframes()), dtype="<i2")


def _run(argv: list[str], stdin: bytes | None = None) -> bytes:
    try:
        return subprocess.run(argv, input=stdin, capture_output=True, check=True, timeout=30).stdout
    except (subprocess.CalledProcessError, subprocess.TimeoutExpired) as e:
        raise ConfigError(f"{argv[0]} failed: {getattr(e, 'stderr', b'') or e}") from None


def said_messages(spoken: Spoken, teacher: str, robot: str) -> list[Message]:
    return [
        Said(
            teacher=teacher,
            robot=robot,
            text=spoken.text,
            language="en",
            onset=spoken.onset,
            end=spoken.end,
        )
    ]


def audio_messages(spoken: Spoken, teacher: str, robot: str, voice: Voice) -> list[Message]:
    """One stream of chunks whose speech starts at the onset (sent at once: the stream was
    recorded while the display ran)."""
    chunks = wav_stream([voice(spoken.text)], teacher, robot, spoken.onset - LEAD_S, fast=True)
    return [c.message for c in chunks]


def run(args: argparse.Namespace) -> int:
    robot = check_id(args.robot, "robot")
    teacher_id = check_id(args.teacher, "teacher")
    if args.traces < 0 or args.max_rate <= 0:
        raise ConfigError("--traces must be >= 0 and --max-rate > 0")
    profile = profile_from(args)
    m = load_map(args.task)
    seed = args.seed if args.seed is not None else random.SystemRandom().randrange(2**31)
    voice = Voice(args.voice) if args.audio else None
    if voice is not None:  # every phrase it may say, before joining: no delay later
        for meaning in ("goal", "excellent", "good", "bad", "terrible", "forward", "left", "right"):
            voice(load_vocabulary().meanings[meaning].phrases["en"][0])
    skew = args.clock_skew

    def clock() -> float:
        return time.time() + skew

    with Node("simteacher", bus_config("simteacher", args)) as node:
        core = SimulatedTeacher(m, load_vocabulary(), profile, seed=seed)
        teacher = BusTeacher(core, args.traces, args.max_rate, counters=node.counters)
        session = node.session_id
        node.input("obs", robot_key(session, robot, "obs"))
        node.input("notice", teacher_key(session, teacher_id, "notice"))
        topic = "audio" if voice else "said"
        out = node.output(topic, teacher_key(session, teacher_id, topic))
        node.log.info(
            "teaching",
            extra=fields(
                robot=robot,
                teacher=teacher_id,
                task=m.name,
                speaks=topic,
                seed=seed,
                traces=args.traces,
                noise=args.noise,
                delay=args.delay,
            ),
        )
        with ClockSync(
            node,
            teacher_id,
            synced=lambda e: node.log.info(
                "clock synced", extra=fields(offset=f"{e.offset:+.4f}", rtt=f"{e.rtt:.4f}")
            ),
            problem=lambda text: node.log.warning(text, extra=fields(teacher=teacher_id)),
            clock=clock,
        ):
            for event in node.events(tick=1.0):
                if not isinstance(event, Input):
                    continue
                message = event.message
                if isinstance(message, Observation):
                    for spoken in teacher.on_observation(message, clock()):
                        messages = (
                            audio_messages(spoken, teacher_id, robot, voice)
                            if voice
                            else said_messages(spoken, teacher_id, robot)
                        )
                        for said in messages:
                            out.put(said)
                elif isinstance(message, TeacherNotice):
                    node.counters[f"notice.{message.kind}"] += 1
    return 0

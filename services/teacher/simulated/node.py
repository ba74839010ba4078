"""`voxshape sim-teacher`: the simulated teacher on the bus, speaking through the normal path.

Inputs:  voxshape/<session>/robot/<robot>/obs              what it watches
         voxshape/<session>/robot/<robot>/help             the robot's questions (it answers)
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
reaction would land hundreds of steps late). It never says more than
`--max-words-per-robot-s` words a robot second (a person says at most 2-3 a second); the
arbiter must be told it lives in robot time (`voxshape arbiter --robot-time <teacher>`), or it
refuses the fast-forwarded words as a flood and credits them with a person's delays.
"""

from __future__ import annotations

import argparse
import os
import random
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import replace

from protocol import (
    HelpRequest,
    Message,
    Observation,
    Said,
    TeacherNotice,
    check_id,
    load_vocabulary,
    robot_key,
)
from services.runtime import (
    ConfigError,
    Input,
    Node,
    Output,
    add_bus_arguments,
    bus_config,
    fields,
)
from services.runtime.settings import add_settings_argument, replaced
from services.teacher.session import join_as_teacher
from services.teacher.simulated.display import DisplayTeacher, Spoken
from services.teacher.simulated.synthesis import LEAD_S, VOICE, Voice
from services.teacher.simulated.teacher import (
    PERSON,
    PROFILES,
    TIRELESS,
    Confusion,
    SimulatedTeacher,
    TeacherProfile,
)
from services.teacher.sources import wav_stream
from services.world.maps import add_task_argument, load_map


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    env = os.environ.get
    parser.add_argument("--robot", default=env("VOXSHAPE_ROBOT", "r1"), help="(VOXSHAPE_ROBOT)")
    parser.add_argument(
        "--teacher", default=env("VOXSHAPE_TEACHER", "simteacher"), help="(VOXSHAPE_TEACHER)"
    )
    add_task_argument(parser, "for the true distance to the goal")
    parser.add_argument(
        "--noise",
        type=float,
        help="share of its judgements it gets wrong (the opposite qualifier); recognition "
        "errors are the speech service's",
    )
    parser.add_argument(
        "--teacher-profile",
        choices=tuple(PROFILES),
        default="person",
        help=f"person: {PERSON.describe()}; tireless: {TIRELESS.describe()} (about 50 words "
        "a minute); --set changes it",
    )
    add_settings_argument(
        parser, "TeacherProfile (services/teacher/simulated/teacher.py)", "words_per_robot_minute=2"
    )
    parser.add_argument(
        "--traces",
        type=int,
        default=0,
        help="dictate the first N episodes it sees start: commands along the shortest path",
    )
    parser.add_argument(
        "--max-words-per-robot-s",
        type=float,
        default=DisplayTeacher.MAX_WORDS_PER_ROBOT_S,
        help="at most this many words a robot second, whatever the profile (the arbiter takes 4)",
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
    """The --teacher-profile with --noise and the --set settings applied."""
    profile = PROFILES[args.teacher_profile]
    if args.noise is not None:
        profile = replace(profile, noise=args.noise)
    try:
        profile = replaced(profile, args.set)
        # Over the bus the speech service mishears: the teacher's own errors are slips.
        return replace(profile, confusion=Confusion(wrong_qualifier=1.0, misheard=0.0))
    except ValueError as e:
        raise ConfigError(f"sim-teacher: {e}") from None


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


def _voice(name: str) -> Voice:
    """The espeak-ng voice, every phrase it may say made before joining (no delay later)."""
    voice = Voice(name)
    for meaning in ("goal", "excellent", "good", "bad", "terrible", "forward", "left", "right"):
        voice(load_vocabulary().meanings[meaning].phrases["en"][0])
    return voice


def _join(
    node: Node, stack: ExitStack, teacher: str, topic: str, clock: Callable[[], float]
) -> Output:
    """Joins as a teacher that speaks on `topic`; its clock synced as a person's client's."""
    (out,) = join_as_teacher(
        node,
        stack,
        teacher,
        (topic,),
        synced=lambda e: node.log.info(
            "clock synced", extra=fields(offset=f"{e.offset:+.4f}", rtt=f"{e.rtt:.4f}")
        ),
        problem=lambda text: node.log.warning(text, extra=fields(teacher=teacher)),
        clock=clock,
        echo=False,
    ).values()
    return out


def run(args: argparse.Namespace) -> int:
    robot = check_id(args.robot, "robot")
    teacher_id = check_id(args.teacher, "teacher")
    if args.traces < 0 or args.max_words_per_robot_s <= 0:
        raise ConfigError("--traces must be >= 0 and --max-words-per-robot-s > 0")
    profile = profile_from(args)
    m = load_map(args.task)
    seed = args.seed if args.seed is not None else random.SystemRandom().randrange(2**31)
    voice = _voice(args.voice) if args.audio else None
    skew = args.clock_skew

    def clock() -> float:
        return time.time() + skew

    with Node("simteacher", bus_config("simteacher", args)) as node, ExitStack() as stack:
        core = SimulatedTeacher(m, load_vocabulary(), profile, seed=seed)
        teacher = DisplayTeacher(
            core, args.traces, args.max_words_per_robot_s, counters=node.counters
        )
        node.input("obs", robot_key(node.session_id, robot, "obs"))
        if profile.answers:
            node.input("help", robot_key(node.session_id, robot, "help"))
        topic = "audio" if voice else "said"
        out = _join(node, stack, teacher_id, topic, clock)
        node.log.info(
            "teaching",
            extra=fields(
                robot=robot,
                teacher=teacher_id,
                task=m.name,
                speaks=topic,
                seed=seed,
                traces=args.traces,
                profile=profile.describe(),
                noise=profile.noise,
            ),
        )
        for event in node.events(tick=1.0):
            match event:
                case Input(message=Observation() as obs):
                    for spoken in teacher.on_observation(obs, clock()):
                        for said in (
                            audio_messages(spoken, teacher_id, robot, voice)
                            if voice
                            else said_messages(spoken, teacher_id, robot)
                        ):
                            out.put(said)
                case Input(message=HelpRequest() as question):
                    teacher.on_question(question)
                case Input(message=TeacherNotice() as notice):
                    node.counters[f"notice.{notice.kind}"] += 1
    return 0

"""`voxshape sim-teacher`: the simulated teacher on the bus, speaking through the normal path.

Its flows are its `simteacher` row of voxshape/protocol/dataflow.py
(`voxshape dataflow --docstring simteacher`).

It watches its robot's observations and answers its questions; the arbiter's notices are
counted, the clock exchange is a thread (voxshape/runtime/clock.py). Its words go out as said
text, for the mock speech engine, or synthesized (--audio) for pocketsphinx: recognition
errors are then real.

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
import random
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, replace

from voxshape.protocol import (
    HelpRequest,
    Message,
    Observation,
    Said,
    TeacherNotice,
    check_id,
    load_vocabulary,
)
from voxshape.runtime import (
    ConfigError,
    Input,
    Node,
    Output,
    add_bus_arguments,
    bus_config,
    fields,
)
from voxshape.runtime.settings import (
    add_options,
    add_settings_argument,
    option,
    read_options,
    replaced,
)
from voxshape.runtime.settings_file import write_run_settings
from voxshape.services.simteacher.display import DisplayTeacher, Spoken
from voxshape.services.simteacher.synthesis import LEAD_S, VOICE, Voice
from voxshape.services.simteacher.teacher import (
    PROFILES,
    Confusion,
    SimulatedTeacher,
    TeacherProfile,
)
from voxshape.teaching.joining import join_as_teacher
from voxshape.teaching.sources import wav_stream
from voxshape.world.maps import load_map, task_option


@dataclass(frozen=True)
class SimTeacherOptions:
    """`voxshape sim-teacher`'s settings (its profile's others: --set)."""

    robot: str = option("r1", "the robot it watches", env="VOXSHAPE_ROBOT")
    teacher: str = option("simteacher", "its id in the session", env="VOXSHAPE_TEACHER")
    task: str = task_option("for the true distance to the goal")
    noise: float | None = option(
        None,
        "share of its judgements it gets wrong (the opposite qualifier); recognition errors "
        "are the speech service's",
        show="the profile's",
    )
    teacher_profile: str = option(
        "person",
        "; ".join(f"{name}: {profile.describe()}" for name, profile in PROFILES.items())
        + " (the tireless teacher: about 50 words a minute); --set changes it",
        choices=tuple(PROFILES),
    )
    traces: int = option(
        0, "dictate the first N episodes it sees start: commands along the shortest path"
    )
    max_words_per_robot_s: float = option(
        DisplayTeacher.MAX_WORDS_PER_ROBOT_S,
        "at most this many words a robot second, whatever the profile (the arbiter takes 4)",
    )
    audio: bool = option(
        False,
        "speak synthesized audio (espeak-ng and sox) to a pocketsphinx speech service "
        "instead of text to the mock engine",
    )
    voice: str = option(VOICE, "--audio: espeak-ng voice")
    clock_skew: float = option(0.0, "its own clock runs this many seconds off")
    seed: int | None = option(None, "random seed", show="drawn, and logged")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    add_options(parser, SimTeacherOptions)
    add_settings_argument(parser, TeacherProfile, "words_per_robot_minute=2")


def profile_from(
    args: argparse.Namespace, options: SimTeacherOptions | None = None
) -> TeacherProfile:
    """The --teacher-profile with --noise and the --set settings applied (`options`: its
    options, already read from `args`)."""
    options = options or read_options(SimTeacherOptions, args)
    profile = PROFILES[options.teacher_profile]
    if options.noise is not None:
        profile = replace(profile, noise=options.noise)
    try:
        profile = replaced(profile, args.set, taken=SimTeacherOptions)
        # Over the bus the speech service mishears: the teacher's own errors are slips.
        return replace(profile, confusion=Confusion(wrong_qualifier=1.0, misheard=0.0, dropped=0.0))
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


def options_from(args: argparse.Namespace) -> SimTeacherOptions:
    """Its options, checked, with the seed drawn when none is given (the one it runs with,
    on record); ConfigError names one it cannot honour."""
    options = read_options(SimTeacherOptions, args)
    check_id(options.robot, "robot")
    check_id(options.teacher, "teacher")
    if options.traces < 0 or options.max_words_per_robot_s <= 0:
        raise ConfigError("--traces must be >= 0 and --max-words-per-robot-s > 0")
    if options.voice != VOICE and not options.audio:
        raise ConfigError(f"--voice {options.voice}: a voice speaks only with --audio")
    if options.seed is None:
        options = replace(options, seed=random.SystemRandom().randrange(2**31))
    return options


def run(args: argparse.Namespace) -> int:
    options = options_from(args)
    robot, teacher_id, seed = options.robot, options.teacher, options.seed
    profile = profile_from(args, options)
    m = load_map(options.task)
    voice = _voice(options.voice) if options.audio else None
    skew = options.clock_skew

    def clock() -> float:
        return time.time() + skew

    bus = bus_config("simteacher", args)
    write_run_settings(bus, "simteacher", options, profile)
    with Node("simteacher", bus) as node, ExitStack() as stack:
        core = SimulatedTeacher(m, load_vocabulary(), profile, seed=seed)
        teacher = DisplayTeacher(
            core, options.traces, options.max_words_per_robot_s, counters=node.counters
        )
        node.subscribe("obs", robot)
        if profile.answers:
            node.subscribe("help", robot)
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
                traces=options.traces,
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

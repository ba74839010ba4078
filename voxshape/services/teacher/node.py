"""`voxshape teach`: speak, stream recordings or type words to a robot of a session.

Its flows are its `teacher` row of voxshape/protocol/dataflow.py
(`voxshape dataflow --docstring teacher`).

It sends microphone or WAV chunks as audio, typed words as utterances (engine "typed"), or,
with --through-speech, as said text (straight out while no speech service). It hears what was
understood and what the arbiter made of it, the clock exchange (a thread), and of the robot
it teaches its status, its questions ("which way?", with the bell) and who answered them; a
placed message is `voxshape placed`'s.

    voxshape teach                              type words (a prompt, or a script on stdin)
    voxshape teach --wav good.wav --wav left.wav   stream recordings in real time (--fast)
    voxshape teach --mic                        speak
    voxshape teach --connect tls/lab.example:7447 --tls-root-ca ca.pem --user ana ...

Typed words are a kept output: those typed while the router restarts reach the arbiter when
it is back. The teacher is told when the speech service goes and comes back.
"""

from __future__ import annotations

import argparse
import getpass
import queue
import sys
import time
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from voxshape.protocol import Utterance, Vocabulary, check_id, load_vocabulary
from voxshape.runtime import ConfigError, Node, Output, add_bus_arguments, bus_config
from voxshape.runtime.audio import AudioError
from voxshape.runtime.settings import add_options, option, read_options
from voxshape.services.teacher.screen import Screen, ask_hint, show_event, terminal_board
from voxshape.services.teacher.senders import MicrophoneSender, ScheduledSender, Sender, TypedSender
from voxshape.teaching.board import Board, SpeechUse, SpeechWatch
from voxshape.teaching.session import join_as_teacher
from voxshape.teaching.sources import (
    TeachError,
    default_teacher_id,
    microphone,
    read_recordings,
    wav_stream,
)

TICK_S = 0.02


@dataclass(frozen=True)
class TeachOptions:
    """`voxshape teach`'s settings."""

    robot: str = option("r1", "the robot taught", env="VOXSHAPE_ROBOT")
    teacher: str | None = option(
        None,
        "your id in the session",
        env="VOXSHAPE_TEACHER",
        show="--user if given, else your login name",
    )
    language: str = option(
        "en", "of typing: one of the vocabulary's (en, es)", env="VOXSHAPE_LANGUAGE"
    )
    wav: tuple[Path, ...] = option(
        (), "stream a recording (not with --mic)", repeat=True, metavar="FILE"
    )
    mic: bool = option(False, "speak into the microphone (not with --wav)")
    device: str | None = option(None, "--mic: input device name or number")
    fast: bool = option(False, "--wav: send at once, not paced")
    through_speech: bool = option(
        False, "typed words go to the speech service's mock engine (said), not straight out"
    )
    linger: float = option(3.0, "seconds to wait for what was understood")
    status_every: float = option(2.0, "seconds between status")
    wait_speech: float = option(5.0, "seconds to wait for a speech service before sending audio")
    vocabulary: Path | None = option(None, "vocabulary file", show="built in")
    json: bool = option(False, "one JSON object per line")
    arrows: bool = option(
        False, "typing at a terminal: the arrow keys send forward, back, left, right at once"
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    add_options(parser, TeachOptions)


def run(args: argparse.Namespace) -> int:
    options = read_options(TeachOptions, args)
    # A person joining a secured session with --user alone is asked for the password.
    ask = getpass.getpass if sys.stdin.isatty() else None
    bus = bus_config("teacher", args, ask=ask, fail_fast=True)
    teacher = check_id(options.teacher or bus.user or default_teacher_id(), "teacher")
    robot = check_id(options.robot, "robot")
    vocabulary = _check_arguments(options)
    screen = Screen(options.json)
    hint = ask_hint(vocabulary, options.language)
    board = terminal_board(bus, teacher, robot, options.status_every, screen, hint)
    mic_chunks: queue.SimpleQueue = queue.SimpleQueue()
    try:
        recordings = read_recordings(list(options.wav))
    except AudioError as e:
        raise ConfigError(str(e)) from None
    with ExitStack() as stack:
        if options.mic:
            try:
                stack.enter_context(
                    microphone(lambda s, t: mic_chunks.put((s, t)), device=options.device)
                )
            except TeachError as e:
                raise ConfigError(str(e)) from None
        node = stack.enter_context(Node("teacher", bus, quiet=True))
        outputs = _join(node, stack, teacher, options, screen)
        for topic in ("obs", "episode", "feedback", "help", "answer"):
            node.subscribe(topic, robot)
        speech = SpeechWatch(_speech_use(options))
        node.watch_presence(role="speech")
        if options.wav or options.mic or options.through_speech:
            _wait_for_speech(node, speech, board, screen, options.wait_speech)
        sender = _sender(
            options, teacher, robot, recordings, mic_chunks, speech, vocabulary, screen
        )
        _loop(node, outputs, sender, speech, board, screen, options.linger)
    if board.robot_never_seen:  # what it said went to no robot: not a success
        screen.note("error", f"robot {robot!r} never appeared; nothing it was told was taught")
        return 1
    return 0


def _check_arguments(options: TeachOptions) -> Vocabulary:
    """Refuses arguments that cannot work; returns the vocabulary (typing needs --language)."""
    if options.wav and options.mic:
        raise ConfigError("--wav and --mic: give one of them (recordings, or the microphone)")
    if min(options.linger, options.status_every, options.wait_speech) < 0:
        raise ConfigError("--linger, --status-every and --wait-speech must be >= 0")
    vocabulary = load_vocabulary(options.vocabulary)
    if not (options.wav or options.mic) and options.language not in vocabulary.languages:
        known = ", ".join(vocabulary.languages)  # typing needs phrases in its language
        raise ConfigError(f"--language {options.language}: the vocabulary has {known} only")
    return vocabulary


def _join(
    node: Node, stack: ExitStack, teacher: str, options: TeachOptions, screen: Screen
) -> dict[type, Output]:
    """Joins as `teacher`, saying audio or typed words (and `said` with --through-speech);
    the clock exchange's result and problems go to the screen."""
    says = ("audio",) if options.wav or options.mic else ("utterance",)
    says += ("said",) if options.through_speech else ()
    return join_as_teacher(
        node,
        stack,
        teacher,
        says,
        synced=lambda e: screen.note(
            "clock",
            f"clock: the arbiter's is {e.offset:+.3f} s from this one "
            f"(+-{e.rtt / 2 * 1000:.1f} ms)",
            offset=e.offset,
            rtt=e.rtt,
        ),
        problem=lambda text: screen.note(
            "warning", f"{text}; your timing is taken as is until one answers"
        ),
    )


def _speech_use(options: TeachOptions) -> SpeechUse:
    """How this teacher's words travel, which decides what losing speech means to it."""
    if options.wav or options.mic:
        return "audio"
    return "through_speech" if options.through_speech else "typed"


def _sender(
    options: TeachOptions,
    teacher: str,
    robot: str,
    recordings: list[np.ndarray],
    mic_chunks: queue.SimpleQueue,
    speech: SpeechWatch,
    vocabulary: Vocabulary,
    screen: Screen,
) -> Sender:
    """What sends: the recordings (--wav), the microphone (--mic) or the typed words."""
    if options.wav:
        start = time.time()
        sender: Sender = ScheduledSender(
            wav_stream(recordings, teacher, robot, start, options.fast)
        )
        screen.note(
            "streaming",
            f"streaming {len(options.wav)} file(s) to robot {robot}",
            files=[str(f) for f in options.wav],
            start_time=start,
        )
        return sender
    if options.mic:
        sender = MicrophoneSender(mic_chunks, teacher, robot)
        screen.note("listening", f"speak to robot {robot} (Ctrl-C to stop)")
        return sender

    def via_speech() -> bool:
        return options.through_speech and speech.available

    return TypedSender(teacher, robot, options.language, via_speech, vocabulary, options.arrows)


def _wait_for_speech(
    node: Node, speech: SpeechWatch, board: Board, screen: Screen, seconds: float
) -> None:
    """Until a speech node is present. What is sent before its subscription reaches this
    client is not lost: the output is kept, and the speech service recovers it."""
    deadline = time.monotonic() + seconds
    while not speech.available and time.monotonic() < deadline:
        event = node.poll(0.05)
        show_event(event, speech, board, screen)
    if not speech.available:
        screen.note(
            "warning",
            f"no speech service listens in session {node.session_id!r} yet: what you say may be "
            "lost (start one with `voxshape speech`, or `voxshape up`)",
        )


def _loop(
    node: Node,
    outputs: dict[type, Output],
    sender: Sender,
    speech: SpeechWatch,
    board: Board,
    screen: Screen,
    linger: float,
) -> None:
    lingering_until = None
    for event in node.events(tick=TICK_S):
        show_event(event, speech, board, screen)
        for message in sender.due():
            outputs[type(message)].put(message)
            if isinstance(message, Utterance):
                board.sent(message, time.monotonic())
        if sender.done:
            if lingering_until is None:
                lingering_until = time.monotonic() + linger
            elif time.monotonic() >= lingering_until and not board.waiting:
                break

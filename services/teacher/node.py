"""`voxshape teach`: speak, stream recordings or type words to a robot of a session.

Outputs: voxshape/<session>/teacher/<teacher>/audio      microphone or WAV chunks
         voxshape/<session>/teacher/<teacher>/utterance  typed words (engine "typed")
         voxshape/<session>/teacher/<teacher>/said       typed words, with --through-speech
                                                         (straight out while no speech service)
Inputs:  voxshape/<session>/teacher/<teacher>/utterance  what was understood
         voxshape/<session>/teacher/<teacher>/notice     what the arbiter made of it
         voxshape/<session>/teacher/<teacher>/clock-reply  the clock exchange (a thread)
         voxshape/<session>/robot/<robot>/obs, episode, feedback   the robot's status
         voxshape/<session>/robot/<robot>/help, answer   its questions ("which way?", with
                                                         the bell) and who answered them

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
import os
import queue
import sys
import time
from contextlib import ExitStack
from pathlib import Path

import numpy as np

from protocol import Utterance, Vocabulary, check_id, load_vocabulary, robot_key
from services.runtime import ConfigError, Node, Output, add_bus_arguments, bus_config
from services.runtime.audio import AudioError
from services.teacher.board import Board, SpeechUse, SpeechWatch
from services.teacher.screen import Screen, ask_hint, show_event, terminal_board
from services.teacher.senders import MicrophoneSender, ScheduledSender, Sender, TypedSender
from services.teacher.session import join_as_teacher
from services.teacher.sources import (
    TeachError,
    default_teacher_id,
    microphone,
    read_recordings,
    wav_stream,
)

TICK_S = 0.02


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    env = os.environ.get
    parser.add_argument("--robot", default=env("VOXSHAPE_ROBOT", "r1"), help="(VOXSHAPE_ROBOT)")
    parser.add_argument(
        "--teacher",
        default=env("VOXSHAPE_TEACHER"),
        help="your id in the session (VOXSHAPE_TEACHER; default: --user if given, else your "
        "login name)",
    )
    parser.add_argument(
        "--language",
        default=env("VOXSHAPE_LANGUAGE", "en"),
        help="of typing: one of the vocabulary's (en, es; VOXSHAPE_LANGUAGE)",
    )
    source = parser.add_mutually_exclusive_group()
    source.add_argument(
        "--wav", type=Path, action="append", metavar="FILE", help="stream a recording (repeat)"
    )
    source.add_argument("--mic", action="store_true", help="speak into the microphone")
    parser.add_argument("--device", help="--mic: input device name or number")
    parser.add_argument("--fast", action="store_true", help="--wav: send at once, not paced")
    parser.add_argument(
        "--through-speech",
        action="store_true",
        help="typed words go to the speech service's mock engine (said), not straight out",
    )
    parser.add_argument(
        "--linger", type=float, default=3.0, help="seconds to wait for what was understood"
    )
    parser.add_argument("--status-every", type=float, default=2.0, help="seconds between status")
    parser.add_argument(
        "--wait-speech",
        type=float,
        default=5.0,
        help="seconds to wait for a speech service before sending audio",
    )
    parser.add_argument("--vocabulary", type=Path, help="vocabulary file (default: built in)")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument(
        "--arrows",
        action="store_true",
        help="typing at a terminal: the arrow keys send forward, back, left, right at once",
    )


def run(args: argparse.Namespace) -> int:
    # A person joining a secured session with --user alone is asked for the password.
    bus = bus_config("teacher", args, ask=getpass.getpass if sys.stdin.isatty() else None)
    teacher = check_id(args.teacher or bus.user or default_teacher_id(), "teacher")
    robot = check_id(args.robot, "robot")
    vocabulary = _check_arguments(args)
    screen = Screen(args.json)
    hint = ask_hint(vocabulary, args.language)
    board = terminal_board(bus, teacher, robot, args.status_every, screen, hint)
    mic_chunks: queue.SimpleQueue = queue.SimpleQueue()
    try:
        recordings = read_recordings(args.wav or [])
    except AudioError as e:
        raise ConfigError(str(e)) from None
    with ExitStack() as stack:
        if args.mic:
            try:
                stack.enter_context(
                    microphone(lambda s, t: mic_chunks.put((s, t)), device=args.device)
                )
            except TeachError as e:
                raise ConfigError(str(e)) from None
        node = stack.enter_context(Node("teacher", bus, quiet=True))
        outputs = _join(node, stack, teacher, args, screen)
        for topic in ("obs", "episode", "feedback", "help", "answer"):
            node.input(topic, robot_key(node.session_id, robot, topic))
        speech = SpeechWatch(_speech_use(args))
        node.watch_presence(role="speech")
        if args.wav or args.mic or args.through_speech:
            _wait_for_speech(node, speech, board, screen, args.wait_speech)
        sender = _sender(args, teacher, robot, recordings, mic_chunks, speech, vocabulary, screen)
        _loop(node, outputs, sender, speech, board, screen, args.linger)
    return 0


def _check_arguments(args: argparse.Namespace) -> Vocabulary:
    """Refuses arguments that cannot work; returns the vocabulary (typing needs --language)."""
    if min(args.linger, args.status_every, args.wait_speech) < 0:
        raise ConfigError("--linger, --status-every and --wait-speech must be >= 0")
    vocabulary = load_vocabulary(args.vocabulary)
    if not (args.wav or args.mic) and args.language not in vocabulary.languages:
        known = ", ".join(vocabulary.languages)  # typing needs phrases in its language
        raise ConfigError(f"--language {args.language}: the vocabulary has {known} only")
    return vocabulary


def _join(
    node: Node, stack: ExitStack, teacher: str, args: argparse.Namespace, screen: Screen
) -> dict[type, Output]:
    """Joins as `teacher`, saying audio or typed words (and `said` with --through-speech);
    the clock exchange's result and problems go to the screen."""
    says = ("audio",) if args.wav or args.mic else ("utterance",)
    says += ("said",) if args.through_speech else ()
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


def _speech_use(args: argparse.Namespace) -> SpeechUse:
    """How this teacher's words travel, which decides what losing speech means to it."""
    if args.wav or args.mic:
        return "audio"
    return "through_speech" if args.through_speech else "typed"


def _sender(
    args: argparse.Namespace,
    teacher: str,
    robot: str,
    recordings: list[np.ndarray],
    mic_chunks: queue.SimpleQueue,
    speech: SpeechWatch,
    vocabulary: Vocabulary,
    screen: Screen,
) -> Sender:
    """What sends: the recordings (--wav), the microphone (--mic) or the typed words."""
    if args.wav:
        start = time.time()
        sender: Sender = ScheduledSender(wav_stream(recordings, teacher, robot, start, args.fast))
        screen.note(
            "streaming",
            f"streaming {len(args.wav)} file(s) to robot {robot}",
            files=[str(f) for f in args.wav],
            start_time=start,
        )
        return sender
    if args.mic:
        sender = MicrophoneSender(mic_chunks, teacher, robot)
        screen.note("listening", f"speak to robot {robot} (Ctrl-C to stop)")
        return sender

    def via_speech() -> bool:
        return args.through_speech and speech.available

    return TypedSender(teacher, robot, args.language, via_speech, vocabulary, args.arrows)


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

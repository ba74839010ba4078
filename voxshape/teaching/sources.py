"""What a teacher gives the session: audio chunks of WAV files or a microphone, typed words.

Audio is cut into 50 ms chunks. A chunk's `capture_time` is the teacher's clock at its first
sample: the moment it was recorded (microphone), or for a file, the moment it would have been
said had it been spoken from the start of the streaming on (paced in real time or not).
"""

from __future__ import annotations

import getpass
import re
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from voxshape.protocol import AudioChunk, Said, Utterance, Vocabulary
from voxshape.protocol.messages import SAMPLE_RATE, Message
from voxshape.runtime.audio import chunks, read_wav, samples_to_pcm

CHUNK_S = 0.05
GAP_BETWEEN_FILES_S = 0.5  # teacher-clock pause between two streamed files


class TeachError(RuntimeError):
    """The teacher's input cannot be used; the message says why and what to do instead."""


def default_teacher_id() -> str:
    """The user's login name as an id (`teacher` when it has nothing usable)."""
    try:
        name = getpass.getuser()
    except (KeyError, OSError):
        name = ""
    name = re.sub(r"[^A-Za-z0-9_.-]", "-", name).strip("-._")[:64]
    return name or "teacher"


def new_stream_id(kind: str) -> str:
    """Unique per stream, so a service never mistakes a new stream for an old one."""
    return f"{kind}-{uuid.uuid4().hex[:12]}"


@dataclass(frozen=True)
class Scheduled:
    """A message and when to send it (seconds after the source started)."""

    due_s: float
    message: Message


def read_recordings(paths: list[Path]) -> list[np.ndarray]:
    """The samples of each WAV file; raises AudioError naming a file that cannot be used."""
    return [read_wav(path) for path in paths]


def wav_stream(
    recordings: list[np.ndarray], teacher: str, robot: str, start_time: float, fast: bool = False
) -> list[Scheduled]:
    """The chunks of the recordings, one stream each, back to back on the teacher's clock; due
    in real time, or all at once (`fast`)."""
    out: list[Scheduled] = []
    clock = 0.0  # seconds after start_time on the teacher's clock
    for samples in recordings:
        stream = new_stream_id("wav")
        pieces = chunks(samples, int(CHUNK_S * SAMPLE_RATE)) or [np.zeros(0, dtype=np.int16)]
        offset = 0
        for seq, piece in enumerate(pieces):
            at = clock + offset / SAMPLE_RATE
            chunk = AudioChunk(
                teacher=teacher,
                robot=robot,
                stream=stream,
                seq=seq,
                sample_rate=SAMPLE_RATE,
                pcm=samples_to_pcm(piece),
                capture_time=start_time + at,
                final=seq == len(pieces) - 1,
            )
            # a chunk can be sent once it has been "recorded", i.e. at its end
            out.append(Scheduled(0.0 if fast else at + len(piece) / SAMPLE_RATE, chunk))
            offset += len(piece)
        clock += len(samples) / SAMPLE_RATE + GAP_BETWEEN_FILES_S
    return out


def typed(
    text: str, teacher: str, robot: str, language: str, at: float, through_speech: bool
) -> Message:
    """A typed line: an Utterance of engine "typed" (confidence 1), or with `through_speech`
    the Said text for the mock speech engine to (mis)hear."""
    if through_speech:
        return Said(teacher=teacher, robot=robot, text=text, language=language, onset=at, end=at)
    return Utterance(
        teacher=teacher,
        robot=robot,
        text=text,
        confidence=1.0,
        onset=at,
        end=at,
        recognized_at=at,
        engine="typed",
        language=language,  # type: ignore[arg-type]
        alternatives=(),
    )


def typed_lines(lines: Iterator[str]) -> Iterator[str]:
    """The words of a script: stripped lines, without blanks and # comments."""
    for line in lines:
        text = line.strip()
        if text and not text.startswith("#"):
            yield text


ARROW_COMMANDS = {"up": "forward", "down": "back", "left": "left", "right": "right"}


def typed_at_terminal(vocabulary: Vocabulary, language: str, arrows: bool) -> Iterator[str]:
    """Lines typed at a prompt with line editing and history (prompt_toolkit); what the
    session prints meanwhile goes above the prompt, never into the line being typed. With
    `arrows`, an arrow key sends its command at once (in `language`)."""
    from prompt_toolkit import PromptSession
    from prompt_toolkit.key_binding import KeyBindings
    from prompt_toolkit.patch_stdout import patch_stdout

    bindings = KeyBindings()
    if arrows:
        for key, action in ARROW_COMMANDS.items():
            phrase = next(
                m.phrases[language][0]
                for m in vocabulary.meanings.values()
                if m.kind == "command" and m.action == action and m.phrases.get(language)
            )

            @bindings.add(key)
            def _send(event: object, phrase: str = phrase) -> None:
                event.app.exit(result=phrase)  # type: ignore[attr-defined]

    prompt = PromptSession(key_bindings=bindings)
    with patch_stdout(raw=True):
        while True:
            try:
                line = prompt.prompt("say> ")
            except (EOFError, KeyboardInterrupt):
                return
            yield from typed_lines([line])


@contextmanager
def microphone(
    on_chunk: Callable[[np.ndarray, float], None], device: str | None = None
) -> Iterator[None]:
    """Calls `on_chunk(samples, capture_time)` for every 50 ms of the default (or named)
    input device while the block runs; raises TeachError when there is no audio library or
    no input device."""
    selected: int | str | None = int(device) if device and device.isdigit() else device
    try:
        import sounddevice
    except OSError as e:  # the wheel is there, the PortAudio library is not
        raise TeachError(
            f"no audio library: {e}. Install PortAudio (Debian: apt-get install libportaudio2), "
            "or stream a recording with --wav FILE, or type your words"
        ) from None
    try:
        sounddevice.check_input_settings(
            device=selected, channels=1, dtype="int16", samplerate=SAMPLE_RATE
        )
    except (sounddevice.PortAudioError, ValueError) as e:
        raise TeachError(
            f"no usable microphone ({e}); list devices with `python -m sounddevice`, choose "
            "one with --device, or stream a recording with --wav FILE, or type your words"
        ) from None

    def callback(indata: np.ndarray, frames: int, _time: object, _status: object) -> None:
        on_chunk(indata[:, 0].copy(), time.time() - frames / SAMPLE_RATE)

    with sounddevice.InputStream(
        samplerate=SAMPLE_RATE,
        channels=1,
        dtype="int16",
        blocksize=int(CHUNK_S * SAMPLE_RATE),
        device=selected,
        callback=callback,
    ):
        yield

"""`voxshape speech`: the speech service on the bus.

Inputs:  voxshape/<session>/teacher/*/audio      audio chunks (cascade, pocketsphinx, vosk, whisper)
         voxshape/<session>/teacher/*/said       text said (mock)
         (an engine's other input is taken only to tell its senders, once, it is not heard)
Outputs: voxshape/<session>/teacher/<t>/utterance  what each teacher was understood to say
                                                   (kept: an arbiter that missed it recovers it)
         voxshape/<session>/teacher/<t>/notice     speech heard but rejected ("not recognized"),
                                                   or input this engine cannot hear
"""

from __future__ import annotations

import argparse
import os
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

from protocol import (
    AudioChunk,
    Said,
    Utterance,
    Vocabulary,
    load_vocabulary,
    parse_key,
    teacher_key,
)
from services.runtime import (
    ConfigError,
    Input,
    Node,
    Output,
    Tick,
    add_bus_arguments,
    bus_config,
    fields,
    worth_logging,
)
from services.speech.engines import open_recognizer
from services.speech.mock import MockRecognizer, MockSettings
from services.speech.pocketsphinx_engine import PocketsphinxSettings
from services.speech.recognizer import DEFAULT_ENGINE, ENGINES, EngineError, Recognizer
from services.speech.streams import AudioStreams, StreamLimits
from services.speech.transcriber import AudioTranscriber, MockTranscriber, Recognized, Unheard

TICK_S = 0.02  # idle streams and due mock results are looked at this often


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    env = os.environ.get
    parser.add_argument(
        "--engine",
        choices=ENGINES,
        default=env("VOXSHAPE_SPEECH_ENGINE", DEFAULT_ENGINE),
        help="cascade (default): pocketsphinx, then Whisper on what it is not sure of; "
        "pocketsphinx: offline English; vosk: needs --model; whisper: offline, Whisper "
        "tiny.en unless --model (pip install -e '.[whisper]'); mock: text in (said messages), "
        "text out (VOXSHAPE_SPEECH_ENGINE)",
    )
    parser.add_argument(
        "--language",
        default=env("VOXSHAPE_LANGUAGE", "en"),
        help="language of the audio engines, one of the vocabulary's (en, es; VOXSHAPE_LANGUAGE); "
        "the mock takes each message's",
    )
    parser.add_argument(
        "--model",
        type=Path,
        help="vosk: the model folder (default VOSK_MODEL_PATH); pocketsphinx (and the "
        "cascade's first stage): an acoustic "
        "model folder instead of the bundled US-English one; whisper: a CTranslate2 Whisper "
        "model folder instead of the packaged tiny.en",
    )
    parser.add_argument("--dictionary", type=Path, help="pocketsphinx: pronunciation dictionary")
    parser.add_argument(
        "--vocabulary",
        type=Path,
        default=env("VOXSHAPE_VOCABULARY"),
        help="vocabulary file (default: built in; VOXSHAPE_VOCABULARY, as the arbiter's)",
    )
    _pocketsphinx_arguments(parser)
    _mock_arguments(parser)
    limits = StreamLimits()
    parser.add_argument("--max-streams", type=int, default=limits.max_streams)
    parser.add_argument(
        "--idle-timeout",
        type=float,
        default=limits.idle_timeout_s,
        help="seconds after which a stream without its final chunk is ended",
    )


def _pocketsphinx_arguments(parser: argparse.ArgumentParser) -> None:
    ps = parser.add_argument_group("pocketsphinx rejection of words outside the vocabulary")
    defaults = PocketsphinxSettings()
    ps.add_argument(
        "--distractors",
        type=int,
        default=defaults.distractors,
        help="dictionary words competing with the vocabulary (0: no rejection; more rejects "
        "more and loses more of the vocabulary; default by language: English 1000, Spanish "
        "600, docs/speech.md#accuracy)",
    )
    ps.add_argument("--distractor-weight", type=float, default=defaults.distractor_weight)


def _mock_arguments(parser: argparse.ArgumentParser) -> None:
    mock = parser.add_argument_group("mock engine")
    d = MockSettings()
    mock.add_argument("--error-rate", type=float, default=d.error_rate, help="0..1 of utterances")
    mock.add_argument(
        "--confusion",
        default=f"misheard={d.misheard:g},dropped={d.dropped:g},inserted={d.inserted:g}",
        help="relative weights of the kinds of error",
    )
    mock.add_argument("--latency", type=float, default=d.latency_s, help="seconds after the speech")
    mock.add_argument(
        "--latency-jitter", type=float, default=d.latency_jitter_s, help="+- seconds, uniform"
    )
    mock.add_argument("--seed", type=int, default=d.seed)


def mock_settings(args: argparse.Namespace) -> MockSettings:
    try:
        weights = {
            k.strip(): float(v) for k, v in (p.split("=") for p in args.confusion.split(","))
        }
        unknown = set(weights) - {"misheard", "dropped", "inserted"}
        if unknown:
            raise ValueError(f"unknown kind {sorted(unknown)[0]!r}")
        return MockSettings(
            error_rate=args.error_rate,
            latency_s=args.latency,
            latency_jitter_s=args.latency_jitter,
            seed=args.seed,
            **weights,
        )
    except ValueError as e:
        raise ConfigError(
            f"mock engine: {e} (e.g. --error-rate 0.2 --confusion "
            "misheard=0.6,dropped=0.3,inserted=0.1 --latency 0.3)"
        ) from None


def run(args: argparse.Namespace) -> int:
    vocabulary = _vocabulary(args)
    bus = bus_config("speech", args)
    if args.max_streams < 1 or args.idle_timeout <= 0:
        raise ConfigError("--max-streams must be >= 1 and --idle-timeout > 0")
    # the engine first: a missing model is reported before joining the bus
    engine = MockRecognizer(vocabulary, mock_settings(args)) if args.engine == "mock" else None
    recognizer = None if engine else _audio_engine(args, vocabulary)
    with Node("speech", bus) as node:
        core = _transcriber(node, args, engine, recognizer)
        # The input this engine cannot hear, taken only to tell its senders so.
        unheard_kind = "audio" if engine is not None else "said"
        unheard = Unheard(args.engine, node.counters)
        node.input(unheard_kind, teacher_key(node.session_id, "*", unheard_kind), recover=0.0)
        publish = _publisher(node)
        for event in node.events(tick=TICK_S):
            now = time.time()
            match event:
                case Input(message=AudioChunk() as chunk, key=key) if unheard_kind != "audio":
                    assert isinstance(core, AudioTranscriber)
                    publish(core.on_audio(parse_key(key).owner, chunk, now))
                case Input(message=Said() as said, key=key) if unheard_kind != "said":
                    assert isinstance(core, MockTranscriber)
                    publish(core.on_said(parse_key(key).owner, said, now))
                case Input(message=AudioChunk() | Said() as sent, key=key):
                    teacher = parse_key(key).owner
                    notices = unheard.on_input(teacher, sent.robot, unheard_kind)
                    if notices:  # once per teacher
                        node.log.warning(
                            "input this engine cannot hear",
                            extra=fields(teacher=teacher, sent=unheard_kind, engine=args.engine),
                        )
                    publish(notices)
                case Tick():
                    publish(core.on_tick(now))
        publish(core.close(time.time()))
    return 0


def _vocabulary(args: argparse.Namespace) -> Vocabulary:
    """The vocabulary, which an engine that hears audio needs in --language."""
    vocabulary = load_vocabulary(args.vocabulary)
    if args.engine != "mock" and args.language not in vocabulary.languages:
        raise ConfigError(
            f"--language {args.language}: the vocabulary has no phrases in it; it has "
            f"{', '.join(vocabulary.languages)} (another language needs a --vocabulary file "
            "with its phrases, docs/speech.md)"
        )
    return vocabulary


def _transcriber(
    node: Node,
    args: argparse.Namespace,
    engine: MockRecognizer | None,
    recognizer: Recognizer | None,
) -> AudioTranscriber | MockTranscriber:
    """The mock engine's transcriber of text said, or an audio engine's of audio streams;
    either subscribes to its input, which recovers what it missed."""
    if engine is not None:
        core = MockTranscriber(engine, node.counters)
        node.input("said", teacher_key(node.session_id, "*", "said"))  # recovered
        node.log.info("listening", extra=fields(engine="mock", error_rate=args.error_rate))
        return core
    assert recognizer is not None
    _describe(recognizer, node)
    report = _reporter(node)
    limits = StreamLimits(args.max_streams, args.idle_timeout)
    streams = AudioStreams(limits=limits, counters=node.counters, report=report)
    audio = AudioTranscriber(recognizer, streams, report)
    node.input("audio", teacher_key(node.session_id, "*", "audio"))  # recovered
    node.log.info("listening", extra=fields(engine=args.engine, language=args.language))
    return audio


def _reporter(node: Node) -> Callable[[str, str], None]:
    """Counts the audio streams' problems by kind, logging a few of each."""
    counts: Counter[str] = Counter()

    def report(kind: str, detail: str) -> None:
        counts[kind] += 1
        if worth_logging(counts[kind]):
            node.log.warning(detail, extra=fields(problem=kind, count=counts[kind]))

    return report


def _publisher(node: Node) -> Callable[[list[Recognized]], None]:
    """Puts each result on its teacher's utterance or notice output (declared when first
    needed; utterances kept), and logs what was heard."""
    outputs: dict[tuple[str, str], Output] = {}

    def publish(results: list[Recognized]) -> None:
        for r in results:
            topic = "utterance" if isinstance(r, Utterance) else "notice"
            if (r.teacher, topic) not in outputs:
                key = teacher_key(node.session_id, r.teacher, topic)
                outputs[r.teacher, topic] = node.output(topic, key)  # utterances kept
            outputs[r.teacher, topic].put(r)
            if isinstance(r, Utterance):
                heard = fields(
                    teacher=r.teacher,
                    robot=r.robot,
                    text=r.text,
                    confidence=f"{r.confidence:.2f}",
                    after_end_s=f"{r.recognized_at - r.end:.2f}",
                )
                node.log.info("heard", extra=heard)

    return publish


def _audio_engine(args: argparse.Namespace, vocabulary: Vocabulary) -> Recognizer:
    if (args.distractors is not None and args.distractors < 0) or args.distractor_weight <= 0:
        raise ConfigError("--distractors must be >= 0 and --distractor-weight > 0")
    settings = PocketsphinxSettings(
        distractors=args.distractors, distractor_weight=args.distractor_weight
    )
    try:
        return open_recognizer(
            args.engine, vocabulary, args.language, args.model, args.dictionary, settings
        )
    except EngineError as e:
        raise ConfigError(str(e)) from None


def _describe(recognizer: Recognizer, node: Node) -> None:
    missing = getattr(recognizer, "unpronounceable", [])
    if missing:
        fix = (
            "say them with words the model knows"
            if recognizer.engine == "vosk"
            else "add it with --dictionary"
        )
        node.log.warning(
            f"phrases left out: a word is not in the {recognizer.engine} lexicon ({fix})",
            extra=fields(phrases=",".join(missing)),
        )
    if getattr(recognizer, "missing", ""):
        node.log.warning(
            f"the cascade has no Whisper stage: pocketsphinx alone hears ({recognizer.missing})"
        )
    node.log.info(
        f"{recognizer.engine} ready",
        extra=fields(
            language=recognizer.language, distractors=getattr(recognizer, "distractor_count", "-")
        ),
    )

"""`voxshape speech`: the speech service on the bus.

Its flows are its `speech` row of voxshape/protocol/dataflow.py
(`voxshape dataflow --docstring speech`).

The audio engines (cascade, pocketsphinx, vosk, whisper) hear audio, the mock text said; an
engine's other input is taken only to tell its senders, once, it is not heard. Utterances are
what each teacher was understood to say (kept: an arbiter that missed one recovers it);
notices, speech heard but rejected ("not recognized"), or input this engine cannot hear.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from voxshape.protocol import (
    AudioChunk,
    Said,
    Utterance,
    Vocabulary,
    load_vocabulary,
    parse_key,
)
from voxshape.recognition.confusion import MOCK
from voxshape.runtime import (
    ConfigError,
    Input,
    Node,
    Tick,
    add_bus_arguments,
    bus_config,
    fields,
    worth_logging,
)
from voxshape.runtime.settings import add_options, flag_of, option, read_options
from voxshape.runtime.settings_file import write_run_settings
from voxshape.services.speech.engines import open_recognizer
from voxshape.services.speech.mock import MockRecognizer, MockSettings, confused, weights_text
from voxshape.services.speech.pocketsphinx_engine import PocketsphinxSettings
from voxshape.services.speech.recognizer import (
    DEFAULT_ENGINE,
    DEFAULT_SCORER,
    ENGINES,
    SCORERS,
    EngineError,
    Recognizer,
)
from voxshape.services.speech.streams import AudioStreams, StreamLimits
from voxshape.services.speech.transcriber import (
    AudioTranscriber,
    MockTranscriber,
    Recognized,
    Unheard,
)

TICK_S = 0.02  # idle streams and due mock results are looked at this often


@dataclass(frozen=True)
class SpeechOptions:
    """`voxshape speech`'s settings (its engines' own: PocketsphinxSettings, MockSettings and
    StreamLimits' fields with flags)."""

    engine: str = option(
        DEFAULT_ENGINE,
        "cascade: pocketsphinx, then a scorer (--scorer) on what it is not sure of; "
        "pocketsphinx: offline English; vosk: needs --model; whisper: offline, Whisper tiny.en "
        "unless --model (pip install -e '.[whisper]'); moonshine: Moonshine base unless "
        "--model (pip install -e '.[moonshine]'); mock: text in (said messages), text out",
        env="VOXSHAPE_SPEECH_ENGINE",
        choices=ENGINES,
    )
    language: str = option(
        "en",
        "language of the audio engines, one of the vocabulary's (en, es); the mock takes each "
        "message's",
        env="VOXSHAPE_LANGUAGE",
    )
    model: Path | None = option(
        None,
        "vosk: the model folder (default VOSK_MODEL_PATH); pocketsphinx (and the cascade's "
        "first stage): an acoustic model folder instead of the bundled US-English one; "
        "whisper: a CTranslate2 Whisper model folder instead of the packaged tiny.en",
    )
    dictionary: Path | None = option(None, "pocketsphinx: pronunciation dictionary")
    scorer: str = option(
        DEFAULT_SCORER,
        "the cascade's second stage: whisper (tiny.en) or moonshine (base, pip install -e "
        "'.[moonshine]'); docs/speech.md#models",
        env="VOXSHAPE_SPEECH_SCORER",
        choices=SCORERS,
    )
    scorer_model: Path | None = option(
        None, "the cascade's scorer: a model folder instead of its packaged one"
    )
    vocabulary: Path | None = option(
        None, "vocabulary file (as the arbiter's)", env="VOXSHAPE_VOCABULARY", show="built in"
    )
    confusion: str = option(
        weights_text(MockSettings()), "relative weights of the kinds of error", group=MOCK
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    add_options(parser, SpeechOptions)
    add_options(parser, PocketsphinxSettings)
    add_options(parser, MockSettings)
    add_options(parser, StreamLimits)


def run(args: argparse.Namespace) -> int:
    options = read_options(SpeechOptions, args)
    tuning = engine_settings(args, options)
    vocabulary = _vocabulary(options)
    bus = bus_config("speech", args)
    limits = read_options(StreamLimits, args)
    if limits.max_streams < 1 or limits.idle_timeout_s <= 0:
        raise ConfigError("--max-streams must be >= 1 and --idle-timeout > 0")
    # the engine first: a missing model is reported before joining the bus
    if isinstance(tuning, MockSettings):
        engine, recognizer = MockRecognizer(vocabulary, tuning), None
    else:
        engine, recognizer = None, _audio_engine(options, vocabulary, tuning)
    write_run_settings(bus, "speech", options, limits, *([tuning] if tuning else []))
    with Node("speech", bus) as node:
        core = _transcriber(node, options, limits, engine, recognizer)
        # The input this engine cannot hear, taken only to tell its senders so.
        unheard_kind = "audio" if engine is not None else "said"
        unheard = Unheard(options.engine, node.counters)
        node.subscribe(unheard_kind, recover=0.0)
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
                            extra=fields(teacher=teacher, sent=unheard_kind, engine=options.engine),
                        )
                    publish(notices)
                case Tick():
                    publish(core.on_tick(now))
        publish(core.close(time.time()))
    return 0


POCKETSPHINX_ENGINES = ("pocketsphinx", "cascade")  # the cascade's first stage is pocketsphinx


def engine_settings(
    args: argparse.Namespace, options: SpeechOptions
) -> MockSettings | PocketsphinxSettings | None:
    """The engine's own settings: the mock's, pocketsphinx's (the cascade's too), or None
    (vosk, whisper). ConfigError names a setting given that this engine cannot honour."""
    mock = confused(read_options(MockSettings, args), options.confusion)
    pocketsphinx = read_options(PocketsphinxSettings, args)
    engine = options.engine
    refused = None
    if engine == "mock" and options.model is not None:
        refused = f"--model {options.model}: the mock engine hears text and takes no model"
    elif options.dictionary is not None and engine not in POCKETSPHINX_ENGINES:
        refused = f"--dictionary {options.dictionary}: pocketsphinx's and the cascade's"
    elif engine != "mock" and (given := _changed(mock)):
        refused = f"{given}: the mock engine's settings"
    elif engine not in POCKETSPHINX_ENGINES and (given := _changed(pocketsphinx)):
        refused = f"{given}: pocketsphinx's and the cascade's settings"
    if refused is not None:
        raise ConfigError(f"{refused}, which --engine {engine} does not take")
    if engine == "mock":
        return mock
    return pocketsphinx if engine in POCKETSPHINX_ENGINES else None


def _changed(settings: object, defaults: object | None = None) -> str:
    """The flags of `settings`' fields that differ from `defaults` (by default its class's),
    the error kinds' weights as --confusion."""
    defaults = defaults if defaults is not None else type(settings)()
    differ = [
        f
        for f in dataclasses.fields(settings)
        if getattr(settings, f.name) != getattr(defaults, f.name)
    ]
    return ", ".join(sorted({flag_of(f) or "--confusion" for f in differ}))


def _vocabulary(options: SpeechOptions) -> Vocabulary:
    """The vocabulary, which an engine that hears audio needs in --language."""
    vocabulary = load_vocabulary(options.vocabulary)
    if options.engine != "mock" and options.language not in vocabulary.languages:
        raise ConfigError(
            f"--language {options.language}: the vocabulary has no phrases in it; it has "
            f"{', '.join(vocabulary.languages)} (another language needs a --vocabulary file "
            "with its phrases, docs/speech.md)"
        )
    return vocabulary


def _transcriber(
    node: Node,
    options: SpeechOptions,
    limits: StreamLimits,
    engine: MockRecognizer | None,
    recognizer: Recognizer | None,
) -> AudioTranscriber | MockTranscriber:
    """The mock engine's transcriber of text said, or an audio engine's of audio streams;
    either subscribes to its input, which recovers what it missed."""
    if engine is not None:
        core = MockTranscriber(engine, node.counters)
        node.subscribe("said")  # recovered
        error_rate = engine.settings.error_rate
        node.log.info("listening", extra=fields(engine="mock", error_rate=error_rate))
        return core
    assert recognizer is not None
    _describe(recognizer, node)
    report = _reporter(node)
    streams = AudioStreams(limits=limits, counters=node.counters, report=report)
    audio = AudioTranscriber(recognizer, streams, report)
    node.subscribe("audio")  # recovered
    node.log.info("listening", extra=fields(engine=options.engine, language=options.language))
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
    """Puts each result on its teacher's utterance or notice key (utterances kept), and logs
    what was heard."""

    def publish(results: list[Recognized]) -> None:
        for r in results:
            node.publish(r)
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


def _audio_engine(
    options: SpeechOptions, vocabulary: Vocabulary, tuning: PocketsphinxSettings | None
) -> Recognizer:
    settings = tuning or PocketsphinxSettings()
    if (settings.distractors or 0) < 0 or settings.distractor_weight <= 0:
        raise ConfigError("--distractors must be >= 0 and --distractor-weight > 0")
    try:
        return open_recognizer(
            options.engine,
            vocabulary,
            options.language,
            options.model,
            options.dictionary,
            settings,
            scorer=options.scorer,
            scorer_model=options.scorer_model,
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

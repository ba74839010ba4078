"""The speech service's cores without a bus: segmentation on synthetic and recorded signals,
stream clocks and problems, pocketsphinx on the WAV fixtures, the mock engine, and the errors
of engines that cannot run."""

from __future__ import annotations

import dataclasses
import runpy
import wave
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from benchmarks.speech import scoring
from voxshape.protocol import AudioChunk, Said, Utterance, load_vocabulary
from voxshape.protocol.messages import SAMPLE_RATE
from voxshape.runtime.audio import AudioError, pcm_to_samples, read_wav, samples_to_pcm
from voxshape.services.speech.mock import MockRecognizer, MockSettings
from voxshape.services.speech.recognizer import EngineError, Recognition
from voxshape.services.speech.segmenter import Segmenter, SegmenterConfig
from voxshape.services.speech.streams import AudioStreams, StreamLimits
from voxshape.services.speech.transcriber import MockTranscriber
from voxshape.services.speech.vosk_engine import MODELS_URL, model_folder

FIXTURES = Path(__file__).parent / "fixtures" / "speech"
VOCABULARY = load_vocabulary()
rng = np.random.default_rng(7)


def tone(seconds: float, amplitude: float = 3000.0, hz: float = 300.0) -> np.ndarray:
    t = np.arange(int(seconds * SAMPLE_RATE)) / SAMPLE_RATE
    return (amplitude * np.sin(2 * np.pi * hz * t)).astype(np.int16)


def syllables(seconds: float, amplitude: float = 3000.0) -> np.ndarray:
    """A tone whose loudness swings like syllables do (4 per second, about 20 dB)."""
    t = np.arange(int(seconds * SAMPLE_RATE)) / SAMPLE_RATE
    envelope = 0.1 + 0.9 * np.sin(np.pi * 4 * t) ** 2
    return (amplitude * envelope * np.sin(2 * np.pi * 300 * t)).astype(np.int16)


def hiss(seconds: float, level: float = 30.0) -> np.ndarray:
    return rng.normal(0.0, level, int(seconds * SAMPLE_RATE)).astype(np.int16)


def segment_all(samples: np.ndarray, chunk: int = 800, config: SegmenterConfig | None = None):
    segmenter = Segmenter(config)
    out = []
    for i in range(0, len(samples), chunk):
        out += segmenter.feed(samples[i : i + chunk])
    return out + segmenter.flush(), segmenter


def seconds(samples: int) -> float:
    return samples / SAMPLE_RATE


# -- segmentation --------------------------------------------------------------------------


def test_utterances_in_noise_are_found_with_their_bounds():
    signal = np.concatenate([hiss(1.0), tone(0.5), hiss(1.0), tone(0.8), hiss(1.0)])
    segments, _ = segment_all(signal)
    assert [(round(seconds(s.start), 2), round(seconds(s.end), 2)) for s in segments] == [
        (1.0, 1.5),
        (2.5, 3.3),
    ]
    first = segments[0]
    assert seconds(first.start - first.audio_start) == pytest.approx(0.25, abs=0.01)  # pre-roll
    assert seconds(first.audio_start + len(first.samples) - first.end) == pytest.approx(0.25)
    assert not first.cut


def test_short_pauses_stay_in_one_utterance_and_clicks_are_dropped():
    signal = np.concatenate(
        [hiss(0.5), tone(0.3), hiss(0.15), tone(0.3), hiss(0.6), tone(0.04), hiss(0.6)]
    )
    segments, segmenter = segment_all(signal)
    assert len(segments) == 1
    assert seconds(segments[0].end - segments[0].start) == pytest.approx(0.75, abs=0.02)
    assert segmenter.counters["segments.too_short"] == 1


def test_speech_from_the_first_sample_and_digital_silence():
    signal = np.concatenate([syllables(0.4), np.zeros(SAMPLE_RATE, dtype=np.int16), tone(0.3)])
    segments, _ = segment_all(signal)
    assert [seconds(s.start) for s in segments] == pytest.approx([0.0, 1.4], abs=0.05)
    assert segments[1].cut  # the stream ended while speaking: flushed


def test_a_stream_that_begins_with_steady_loud_noise_learns_it_as_the_floor():
    signal = np.concatenate([hiss(1.0, 1500), syllables(0.5, 12000), hiss(1.0, 1500)])
    segments, _ = segment_all(signal)
    assert [seconds(s.start) for s in segments] == pytest.approx([1.0], abs=0.12)


def test_long_speech_is_cut_at_the_maximum_length():
    config = SegmenterConfig(max_speech_s=1.0)
    segments, segmenter = segment_all(
        np.concatenate([hiss(0.3), tone(2.5), hiss(0.5)]), config=config
    )
    assert [round(seconds(s.end - s.start), 2) for s in segments] == [1.0, 1.0, 0.5]
    assert segmenter.counters["segments.cut_at_max_length"] == 2


def test_segments_do_not_depend_on_how_the_audio_is_chunked():
    signal = np.concatenate([hiss(0.5), tone(0.4), hiss(0.5), tone(0.3), hiss(0.4)])
    reference = [(s.start, s.end) for s in segment_all(signal, chunk=SAMPLE_RATE)[0]]
    for chunk in (1, 37, 160, 333, 1600):
        assert [(s.start, s.end) for s in segment_all(signal, chunk=chunk)[0]] == reference


def test_a_noise_floor_that_rises_is_not_taken_for_speech():
    signal = np.concatenate([hiss(1.0, 30), hiss(4.0, 300), tone(0.5, 8000), hiss(1.0, 300)])
    segments, _ = segment_all(signal)
    assert [round(seconds(s.start), 1) for s in segments][-1] == 5.0
    assert len(segments) <= 2  # at most the step itself, while the floor adapts


def test_recorded_noisy_speech_is_found_where_it_is():
    noisy = [c for c in scoring.load_clips(FIXTURES) if c.noise != "none"]
    assert noisy
    for clip in noisy:
        segments, _ = segment_all(read_wav(clip.path))
        assert len(segments) == 1, clip.path.name
        assert seconds(segments[0].start) == pytest.approx(clip.speech_start_s, abs=0.08)
        # a weak final consonant ("sto-p") can fall under a noise this loud
        assert seconds(segments[0].end) == pytest.approx(clip.speech_end_s, abs=0.2)


# -- streams: clocks and problems ------------------------------------------------------------


def chunk(seq: int, samples: np.ndarray, capture_time: float, **fields) -> AudioChunk:
    values = dict(
        teacher="ana",
        robot="r1",
        stream="mic-1",
        seq=seq,
        sample_rate=SAMPLE_RATE,
        pcm=samples_to_pcm(samples),
        capture_time=capture_time,
        final=False,
    )
    return AudioChunk(**{**values, **fields})


def stream_of(signal: np.ndarray, t0: float, chunk_s: float = 0.05, skew: float = 0.0) -> list:
    n = int(chunk_s * SAMPLE_RATE)
    pieces = [signal[i : i + n] for i in range(0, len(signal), n)]
    return [
        chunk(i, p, t0 + i * chunk_s * (1 + skew), final=i == len(pieces) - 1)
        for i, p in enumerate(pieces)
    ]


def test_onset_and_end_are_on_the_teachers_clock():
    streams = AudioStreams()
    t0 = 1_700_000_000.0
    signal = np.concatenate([hiss(1.0), tone(0.5), hiss(1.0)])
    out = [s for c in stream_of(signal, t0, skew=0.01) for s in streams.on_chunk("ana", c, 0.0)]
    assert len(out) == 1 and len(streams) == 0  # the final chunk closed the stream
    # each chunk anchors its samples: 1 % clock skew shows, and does not accumulate
    assert out[0].onset == pytest.approx(t0 + 1.0 * 1.01, abs=0.011)
    assert out[0].end == pytest.approx(t0 + 1.5 * 1.01, abs=0.011)
    assert (out[0].teacher, out[0].robot, out[0].stream) == ("ana", "r1", "mic-1")


def test_stream_problems_are_counted_and_reported_never_raised():
    reported = []
    streams = AudioStreams(
        limits=StreamLimits(max_streams=1, idle_timeout_s=2.0),
        report=lambda kind, detail: reported.append(kind),
    )
    quiet = hiss(0.05)
    assert streams.on_chunk("bob", chunk(0, quiet, 1.0), 0.0) == []  # wrong teacher for key
    streams.on_chunk("ana", chunk(3, quiet, 1.0), 0.0)  # joins late
    streams.on_chunk("ana", chunk(3, quiet, 1.0), 0.0)  # repeated: dropped
    streams.on_chunk("ana", chunk(9, np.zeros(0, np.int16), 1.3), 0.0)  # a gap, and empty
    streams.on_chunk("ana", chunk(0, quiet, 1.0, stream="mic-2"), 0.0)  # one stream too many
    assert streams.on_tick(1.0) == [] and len(streams) == 1
    streams.on_tick(3.5)  # idle beyond the timeout: ended
    assert len(streams) == 0
    assert reported == [
        "wrong_teacher",
        "joined_late",
        "out_of_order",
        "gap",
        "empty",
        "too_many_streams",
        "stream_timed_out",
    ]
    assert streams.counters["audio.gap"] == 1


def test_an_utterance_cut_by_lost_chunks_ends_at_the_gap():
    streams = AudioStreams()
    chunks_ = stream_of(np.concatenate([hiss(0.5), tone(1.0), hiss(0.5)]), 100.0)
    kept = chunks_[:16] + chunks_[20:]  # chunks 16-19 (0.8-1.0 s) lost mid-utterance
    out = [s for c in kept for s in streams.on_chunk("ana", c, 0.0)]
    assert [round(s.onset - 100.0, 2) for s in out] == [0.5, 1.0]
    assert out[0].end == pytest.approx(100.8, abs=0.01)


def test_odd_byte_counts_are_an_audio_error():
    with pytest.raises(AudioError, match="odd count"):
        pcm_to_samples(b"\x00\x01\x02")


# -- pocketsphinx on the recorded fixtures -----------------------------------------------------


def test_fixtures_are_small_16k_mono_and_listed():
    clips = scoring.load_clips(FIXTURES)
    assert len(clips) >= 30
    total = 0
    for clip in clips:
        with wave.open(str(clip.path)) as w:
            assert (w.getframerate(), w.getnchannels(), w.getsampwidth()) == (16000, 1, 2)
        total += clip.path.stat().st_size
        in_vocabulary = VOCABULARY.lookup(clip.text) is not None
        assert in_vocabulary == (clip.kind == "vocabulary"), clip.text
    assert total < 1_000_000
    assert {c.language for c in clips} == {"en", "es"}
    assert {c.kind for c in clips} == {"vocabulary", "oov", "near", "sentence"}


@pytest.fixture(scope="module")
def pocketsphinx_report() -> dict:
    from voxshape.services.speech.pocketsphinx_engine import PocketsphinxRecognizer

    recognizer = PocketsphinxRecognizer(VOCABULARY, "en")
    report = scoring.run(scoring.load_clips(FIXTURES), recognizer)
    return report.summary(VOCABULARY)


def test_pocketsphinx_recognizes_the_clean_english_fixtures(pocketsphinx_report):
    clean = pocketsphinx_report["conditions"]["tune"]["en"]["clean"]
    print(f"pocketsphinx, clean English fixtures: {clean}")
    assert clean["n"] >= 15
    assert clean["accuracy"] >= 0.8  # measured 0.94 (15/16) on this machine
    assert pocketsphinx_report["realtime_factor"] < 0.25  # measured ~0.05; a loaded machine


def test_pocketsphinx_rejects_words_outside_the_vocabulary(pocketsphinx_report):
    outside = pocketsphinx_report["false_accepts"]["tune"]
    print(f"accepted: unrelated {outside['unrelated']}, near misses {outside['near']}")
    assert outside["unrelated"]["rate"] <= 0.25  # measured 0 of 8


def test_pocketsphinx_reports_its_measured_precision_as_confidence(pocketsphinx_report):
    from voxshape.services.speech.pocketsphinx_engine import PRECISION_BY_POSTERIOR

    bands = pocketsphinx_report["calibration"]["tune"]
    measured = {share for _, share in PRECISION_BY_POSTERIOR}
    assert bands and all(float(band) in {0.8, 0.95} for band in bands)  # 0.80 and 0.96 only
    assert all(share >= 0.5 for share in measured)  # the arbiter's gate keeps every phrase


def test_pocketsphinx_without_a_model_for_another_language_says_what_it_needs():
    from voxshape.services.speech.pocketsphinx_engine import PocketsphinxRecognizer

    with pytest.raises(EngineError, match="another language needs a CMU Sphinx acoustic model"):
        PocketsphinxRecognizer(VOCABULARY, "fr")


# -- the benchmark: its plan and its summary ------------------------------------------------

# every English voice of espeak-ng here (`espeak-ng --voices=en`, without mbrola's)
ESPEAK_ENGLISH = [
    "en-gb", "en-us", "en-gb-scotland", "en-gb-x-gbclan", "en-gb-x-rp", "en-gb-x-gbcwmd",
    "en-029", "en-us-nyc",
]  # fmt: skip


def test_the_full_plan_holds_out_voices_words_and_conditions():
    plan = runpy.run_path(str(FIXTURES / "make_fixtures.py"))["full_plan"]()
    tune = [c for c in plan if c.split == "tune"]
    held = [c for c in plan if c.split == "held-out"]
    assert len(tune) + len(held) == len(plan) and len({c.stem for c in plan}) == len(plan)
    # "good" in every English voice espeak-ng has
    espeak = [c for c in plan if c.synthesizer == "espeak-ng"]
    says_good = {c.voice.split("+")[0] for c in espeak if c.text == "good"}
    assert set(ESPEAK_ENGLISH) <= says_good
    # held-out speech of the vocabulary, clean: in voices tuning never hears
    held_voices = {c.voice for c in held if c.kind == "vocabulary" and c.condition == "clean"}
    assert held_voices and held_voices.isdisjoint({c.voice for c in tune})
    # settings are chosen on one synthesizer, and held out on the other whole
    assert {c.synthesizer for c in tune} == {"espeak-ng"}
    assert {c.synthesizer for c in held if c.condition != "clean"} >= {"festival", "espeak-ng"}
    kinds = {"vocabulary", "oov", "near", "sentence"}
    assert {c.kind for c in tune} == {c.kind for c in held} == kinds
    assert all(c.credits == "" or c.kind == "sentence" for c in plan)
    # outside words: none of the held-out ones is a tuning one
    outside = [c for c in plan if c.kind != "vocabulary"]
    tune_words = {c.text for c in outside if c.split == "tune"}
    assert tune_words.isdisjoint(c.text for c in outside if c.split == "held-out")
    assert {c.condition for c in tune} == {"clean", "white 10 dB", "pink 15 dB"}
    assert {c.condition for c in held} == {
        "clean", "level -10 dBFS", "level -20 dBFS", "level -30 dBFS", "telephone", "reverb"
    }  # fmt: skip
    for language in ("en", "es"):  # every phrase in both splits
        for split in (tune, held):
            spoken = {c.text for c in split if c.language == language}
            assert set(VOCABULARY.phrases(language)) <= spoken
    assert {c.kind for c in held if c.language == "es"} == {"vocabulary", "oov"}


def test_old_manifests_load_as_tuning_clips_with_conditions_from_their_noise():
    clips = scoring.load_clips(FIXTURES) + scoring.load_clips(FIXTURES / "ko")
    assert {c.split for c in clips} == {"tune"}
    assert {c.condition for c in clips} == {
        "clean", "white 10 dB", "white 15 dB", "pink 10 dB", "pink 15 dB"
    }  # fmt: skip
    assert all((c.condition == "clean") == (c.noise == "none") for c in clips)


class Says:
    """A recognizer that hears `text` in every segment."""

    engine, language = "stub", "en"

    def __init__(self, text: str | None) -> None:
        self.text = text

    def recognize(self, samples):
        return Recognition(self.text, 1.0) if self.text else None


def test_latency_runs_from_the_end_of_speech_and_conditions_get_quiet_around():
    clip = next(c for c in scoring.load_clips(FIXTURES) if c.path.name == "en-voc-good-en-us.wav")
    for condition in ("clean", "telephone", "reverb", "level -30 dBFS"):
        samples, offset = scoring.as_stream(dataclasses.replace(clip, condition=condition))
        assert offset == scoring.QUIET_S and len(samples) > 2 * scoring.QUIET_S * SAMPLE_RATE
    outcome = scoring.transcribe_clip(clip, Says("good"))
    assert outcome.heard == ["good"]
    # the segmenter waits out its hangover (0.3 s) before it gives the utterance out; the
    # recognizer's own wall-clock time is left out (a benchmark's figure, not a test's)
    assert 0.25 <= outcome.latency_s - outcome.recognize_s <= 0.45
    assert scoring.transcribe_clip(clip, Says(None)).latency_s is None


def test_the_benchmark_counts_what_passes_the_arbiters_confidence_gate():
    clip = next(c for c in scoring.load_clips(FIXTURES) if c.path.name == "en-voc-good-en-us.wav")

    class Unsure(Says):
        def recognize(self, samples):
            return Recognition(self.text, 0.3)

    outcome = scoring.transcribe_clip(clip, Unsure("good"))
    assert outcome.heard == [] and outcome.recognized == [("good", 0.3)]
    summary = scoring.Report("stub", "en", [outcome]).summary(VOCABULARY)
    assert summary["accuracy"] == 0.0
    assert summary["calibration"]["tune"] == {
        "0": {"n": 1, "right": 1, "share": 1.0, "confidence": 0.3}
    }


def test_the_summary_reports_each_split_condition_voice_and_false_accept():
    def outcome(text, heard, split="tune", condition="clean", voice="en-us", kind="vocabulary",
                language="en", latency=0.4):  # fmt: skip
        clip = scoring.Clip(
            Path("x.wav"), text, language, kind, voice, "none", 0.0, 0.0, 1.0, condition, split
        )
        return scoring.Outcome(clip, heard, 0.01, 0.01, 1.0, latency if heard else None)

    outcomes = [
        outcome("good", ["good"]),
        outcome("good", ["bad"]),
        outcome("backwards", ["backward"]),  # same meaning only
        outcome("good", ["good"], voice="en-gb+m3"),
        outcome("good", ["good"], split="held-out", voice="en-029", latency=0.6),
        outcome("left", [], split="held-out", voice="en-029"),
        outcome("left", ["left"], split="held-out", condition="reverb", latency=0.8),
        outcome("hello", ["good"], kind="oov"),
        outcome("goat", [], kind="near"),
        outcome("shop", [], kind="near", split="held-out"),
        outcome("bien", ["good"], language="es"),  # Spanish speech, heard with its meaning
        outcome("terrible", ["terrible"], language="es"),  # also English: not counted
        outcome("bien", ["left"], language="es", split="held-out"),  # another meaning: outside
    ]
    report = scoring.Report("stub", "en", outcomes)
    s = report.summary(VOCABULARY)
    assert (s["accuracy"], s["meaning_accuracy"]) == (0.5, 0.75)
    assert (s["held_out_accuracy"], s["held_out_meaning_accuracy"]) == (0.5, 0.5)
    assert (s["false_accept_rate"], s["held_out_false_accept_rate"]) == (0.333, 0.5)
    assert s["false_accepts"]["tune"] == {
        "near": {"n": 1, "accepted": 0, "rate": 0.0},
        "other language": {"n": 1, "accepted": 0, "rate": 0.0},
        "unrelated": {"n": 1, "accepted": 1, "rate": 1.0},
    }
    assert s["conditions"]["held-out"]["en"]["reverb"]["accuracy"] == 1.0
    assert s["voices"]["tune"]["en"]["en-gb+m3"]["n"] == 1
    assert "reverb" not in s["voices"]["held-out"]["en"]
    assert s["per_word_accuracy"]["en:good"] == {"tune": 0.667, "held-out": 1.0}
    assert s["per_word_accuracy"]["en:left"] == {"tune": None, "held-out": 0.5}
    assert s["latency_p50_s"] == 0.4 and 0.6 < s["latency_p95_s"] < 0.8  # of those heard
    # the Spanish engine's headline is Spanish
    spanish = scoring.Report("stub", "es", outcomes).summary(VOCABULARY)
    assert spanish["accuracy"] == 0.5 and spanish["held_out_accuracy"] == 0.0
    assert spanish["false_accepts"]["tune"]["other language"]["n"] == 6


# -- vosk without a model --------------------------------------------------------------------


def test_a_missing_vosk_model_says_where_to_get_one(tmp_path):
    with pytest.raises(EngineError) as info:
        model_folder(None, "es", env={})
    text = str(info.value)
    assert "none is configured" in text and MODELS_URL in text
    assert "vosk-model-small-es-0.42" in text and "vosk-model-small-en-us-0.15" in text
    assert "--model" in text and "VOSK_MODEL_PATH" in text
    with pytest.raises(EngineError, match="is not a directory"):
        model_folder(tmp_path / "nowhere", "en", env={})
    with pytest.raises(EngineError, match="holds no vosk model"):
        model_folder(None, "en", env={"VOSK_MODEL_PATH": str(tmp_path)})


# -- the mock engine -------------------------------------------------------------------------


def hear_many(settings: MockSettings, n: int, language: str = "en") -> tuple[list, Counter]:
    mock = MockRecognizer(VOCABULARY, settings)
    phrases = VOCABULARY.phrases(language)
    heard = [mock.hear(phrases[i % len(phrases)], language) for i in range(n)]
    return heard, mock.counters


def test_the_mock_is_deterministic_for_a_seed():
    settings = MockSettings(error_rate=0.3, latency_jitter_s=0.1, seed=42)
    assert hear_many(settings, 300)[0] == hear_many(settings, 300)[0]
    other = dataclasses.replace(settings, seed=43)
    assert hear_many(settings, 300)[0] != hear_many(other, 300)[0]


@pytest.mark.parametrize("error_rate", [0.0, 0.2, 0.5])
def test_the_mock_error_rate_and_confusion_match_the_settings(error_rate):
    n = 4000
    settings = MockSettings(error_rate=error_rate, misheard=2, dropped=1, inserted=1, seed=1)
    heard, counters = hear_many(settings, n, "es")
    errors = n - counters["mock.correct"]
    tolerance = 4 * np.sqrt(max(error_rate * (1 - error_rate), 1e-9) / n)  # 4 sigma
    assert errors / n == pytest.approx(error_rate, abs=tolerance + 1e-9)
    if error_rate:
        assert counters["mock.misheard"] / errors == pytest.approx(0.5, abs=0.06)
        assert counters["mock.dropped"] / errors == pytest.approx(0.25, abs=0.06)
    # what comes out matches what was counted
    assert sum(len(h) == 0 for h in heard) == counters["mock.dropped"]
    assert sum(len(h) == 2 for h in heard) == counters["mock.inserted"]
    assert all(VOCABULARY.lookup(x.text) for h in heard for x in h)


def test_the_mock_rejects_words_outside_the_vocabulary_and_keeps_its_latency():
    mock = MockRecognizer(VOCABULARY, MockSettings(latency_s=0.4, latency_jitter_s=0.1, seed=3))
    assert mock.hear("banana", "en") == [] and mock.counters["mock.out_of_vocabulary"] == 1
    assert mock.hear("good", "es") == []  # not a Spanish phrase
    heard = [mock.hear("Muy bien!", "es")[0] for _ in range(200)]
    assert {h.text for h in heard} == {"muy bien"}
    assert all(0.3 <= h.delay_s <= 0.5 for h in heard)
    with pytest.raises(ValueError, match="error rate"):
        MockSettings(error_rate=1.5)


def test_mock_results_come_out_when_their_latency_is_due():
    core = MockTranscriber(MockRecognizer(VOCABULARY, MockSettings(latency_s=0.5, seed=0)))
    said = Said(teacher="ana", robot="r1", text="left", language="en", onset=10.0, end=10.4)
    assert core.on_said("ana", said, now=100.0) == []
    assert core.on_tick(100.4) == []
    (utterance,) = core.on_tick(100.5)
    assert (utterance.text, utterance.engine, utterance.onset, utterance.end) == (
        "left",
        "mock",
        10.0,
        10.4,
    )
    assert utterance.recognized_at == 100.5
    assert core.on_said("bob", said, now=101.0) == []  # said on another teacher's key
    assert core.counters["said.wrong_teacher"] == 1


def test_a_said_text_heard_again_is_heard_the_same():
    """A restarted speech service hears again what the teacher's kept output recovers, after
    other words or none: the same utterances (ids, texts), so the arbiter drops the copies
    instead of crediting a word twice, even when the mock mishears or inserts a word."""
    settings = MockSettings(latency_s=0.0, error_rate=0.5, misheard=1, dropped=1, inserted=2)
    said = [  # ids fixed: the mock's draws depend on them alone
        Said(
            id=f"said-{t}",
            teacher="ana",
            robot="r1",
            text="good",
            language="en",
            onset=t,
            end=t + 0.4,
        )
        for t in range(40)
    ]

    def heard(messages: list[Said]) -> dict[str, list[tuple[str, str]]]:
        core = MockTranscriber(MockRecognizer(VOCABULARY, settings))
        return {
            s.id: [
                (u.id, u.text)
                for u in core.on_said("ana", s, now=100.0) + core.close(100.0)
                if isinstance(u, Utterance)
            ]
            for s in messages
        }

    before = heard(said)  # the service before its crash
    after = heard(said[25:])  # after: only the recovered ones
    assert all(after[s.id] == before[s.id] for s in said[25:])
    kinds = {len(u) for u in before.values()}
    assert kinds == {0, 1, 2}  # dropped, heard (or misheard), and a word inserted
    ids = [i for u in before.values() for i, _ in u]
    assert len(ids) == len(set(ids))

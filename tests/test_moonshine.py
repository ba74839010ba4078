"""The moonshine engine: its tokenizer (SentencePiece BPE from the pieces alone), its errors
(no model, an incomplete or corrupt folder, another language), and Moonshine base of the
moonshine-cpp package on committed clips, offline. The model tests skip without the
`moonshine` extra."""

from __future__ import annotations

import sys
from importlib.util import find_spec
from pathlib import Path

import pytest

from benchmarks.speech import scoring
from tests.test_speech import FIXTURES, VOCABULARY
from voxshape.services.speech import moonshine_engine
from voxshape.services.speech.engines import open_recognizer
from voxshape.services.speech.moonshine_engine import MoonshineRecognizer, Pieces
from voxshape.services.speech.recognizer import EngineError

needs_moonshine = pytest.mark.skipif(
    find_spec("moonshine_cpp") is None or find_spec("onnxruntime") is None,
    reason="moonshine-cpp or onnxruntime is not installed: pip install -e '.[moonshine]'",
)
CLIPS = {c.path.name: c for c in scoring.load_clips(FIXTURES)}


def pieces(*merged: str) -> bytes:
    """A tokenizer.bin: <unk> <s> </s>, the 256 bytes, then `merged` and single letters."""
    items = [b"<unk>", b"<s>", b"</s>", *(bytes([b]) for b in range(256))]
    items += [m.encode() for m in merged]
    items += [c.encode() for c in "▁abcdefghijklmnopqrstuvwxyzG."]
    return b"".join(bytes([len(p)]) + p for p in items)


def test_the_tokenizer_merges_the_lowest_ranked_pair_first_and_falls_back_to_bytes():
    tok = Pieces(pieces("▁G", "o", "▁Go", "al", "oa"))
    ids = {p: tok.ids[p] for p in ("▁Go", "al", ".")}
    # "o" "a" could merge into "oa", but "▁Go" (rank 261) comes first, then "al" (262)
    assert tok.encode("Goal.") == [ids["▁Go"], ids["al"], ids["."]]
    assert tok.decode(tok.encode("Goal.")) == "Goal."
    assert tok.encode("é")[-2:] == [3 + 0xC3, 3 + 0xA9]  # no piece: its UTF-8 bytes
    with pytest.raises(ValueError, match="too few"):
        Pieces(b"\x05<unk>")


def test_a_missing_model_names_the_install(monkeypatch, tmp_path):
    monkeypatch.setattr(moonshine_engine.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(EngineError, match=r"moonshine-cpp.*pip install -e '\.\[moonshine\]'"):
        MoonshineRecognizer(VOCABULARY, "en")
    with pytest.raises(EngineError, match=r"--model '/nonexistent': not a directory"):
        MoonshineRecognizer(VOCABULARY, "en", Path("/nonexistent"))
    (tmp_path / "encoder_model.onnx").write_bytes(b"")
    with pytest.raises(EngineError, match=r"no decoder_model_merged, tokenizer.bin;.*--model"):
        MoonshineRecognizer(VOCABULARY, "en", tmp_path)


def test_a_corrupt_model_file_is_an_engine_error_naming_the_folder(tmp_path):
    for name in ("encoder_model.onnx", "decoder_model_merged.onnx"):
        (tmp_path / name).write_bytes(b"not a model")
    (tmp_path / "tokenizer.bin").write_bytes(pieces())
    if find_spec("onnxruntime") is None:
        pytest.skip("onnxruntime is not installed")
    with pytest.raises(EngineError, match=r"failed to load \(.*\); give --model a Moonshine"):
        MoonshineRecognizer(VOCABULARY, "en", tmp_path)


def test_missing_onnxruntime_names_the_install(monkeypatch, tmp_path):
    for name in ("encoder_model.onnx", "decoder_model_merged.onnx", "tokenizer.bin"):
        (tmp_path / name).write_bytes(b"")
    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # its import fails
    with pytest.raises(EngineError, match=r"needs onnxruntime.*pip install -e '\.\[moonshine\]'"):
        MoonshineRecognizer(VOCABULARY, "en", tmp_path)


def test_it_hears_english_only():
    with pytest.raises(EngineError, match=r"English only.*--language es"):
        MoonshineRecognizer(VOCABULARY, "es")


@pytest.fixture(scope="module")
def recognizer() -> MoonshineRecognizer:
    recognizer = open_recognizer("moonshine", VOCABULARY, "en")
    assert isinstance(recognizer, MoonshineRecognizer)
    return recognizer


@needs_moonshine
def test_moonshine_base_scores_the_phrases_against_their_rivals(recognizer):
    clip = scoring.as_stream(CLIPS["en-voc-turn-left-kal-diphone.wav"])[0]
    scored = recognizer.likeliest(clip, hint="you made it")
    assert scored.best() == "turn left" and "you made it" in scored.phrases
    margins = recognizer.margins(scored, "turn left")
    assert margins.free > 0 and margins.other_phrase > 0 and margins.other_kind > 0
    assert recognizer.has_sound_alikes("goal")  # "Go." ends where "Goal." goes on
    outcome = scoring.transcribe_clip(CLIPS["en-oov-coffee-en-us-klatt.wav"], recognizer)
    assert outcome.heard == []

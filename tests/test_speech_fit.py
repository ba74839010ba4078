"""Fitting the decision (benchmarks/speech/fit.py) on rows as collect.py writes them: the
threshold holds the tuning near misses back, the kind margin keeps a judgement from being
taken for a command, pocketsphinx alone and the cascade decide as the engines do; and a
candidate model that is not what it should be is refused, naming the fix."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmarks.speech import fit, models, scoring
from tests.test_speech import VOCABULARY

# free, sound_alike, other_phrase, ps_agrees, ps_posterior, prior, other_kind
SURE = [6.0, 5.0, 5.0, 0.0, 0.0, 4.0, 6.0]
UNSURE = [-1.0, -1.0, 2.0, 0.0, 0.0, -2.0, 2.0]


def clip(text: str, kind: str, split: str = "tune", name: str = "") -> scoring.Clip:
    path = Path(name or f"{kind}-{text}-{split}.wav")
    return scoring.Clip(path, text, "en", kind, "v", "none", 0.0, 0.0, 0.5, split=split)


def row(c: scoring.Clip, best: str, margins: list[float], ps=None, alikes=True) -> dict:
    return {
        "file": c.path.name,
        "at": 1.0,
        "audio_s": 1.0,
        "pocketsphinx": ps,
        "pocketsphinx_s": 0.01,
        "scorer_s": 0.1,
        "best": best,
        "candidates": {best: margins},
        "spotted": None,
        "transcript": "",
        "alikes": {best: alikes},
    }


def dataset() -> list[tuple[scoring.Clip, list[dict]]]:
    data = []
    for i in range(20):  # phrases heard clearly, near misses that look like them but less
        said = clip("good", "vocabulary", name=f"good{i}.wav")
        data.append((said, [row(said, "good", [s + i / 10 for s in SURE])]))
        near = clip("could", "near", name=f"could{i}.wav")
        data.append((near, [row(near, "good", [u + i / 10 for u in UNSURE])]))
    bad = clip("bad", "vocabulary", name="bad-as-back.wav")  # a command a little ahead
    data.append((bad, [row(bad, "back", [6.5, 5.5, 5.5, 0.0, 0.0, 4.5, 5.0])]))
    return data


def test_the_fitted_threshold_holds_back_the_tuning_near_misses():
    v = next(x for x in fit.VARIANTS if x.name == "scorer + sound-alikes + prior-corrected")
    d = fit.fit_variant(dataset(), v, VOCABULARY)
    outs = fit.outcomes(dataset(), v, d)
    near = [bool(o.heard) for o in outs if o.clip.kind == "near"]
    assert sum(near) / len(near) <= fit.NEAR_MISSES
    assert all(o.heard == ["good"] for o in outs if o.clip.text == "good")


def test_the_kind_margin_keeps_a_judgement_from_being_heard_as_a_command():
    v = next(x for x in fit.VARIANTS if x.name == "scorer + sound-alikes")
    d = fit.fit_variant(dataset(), v, VOCABULARY)
    assert d.kind_margin > 0.5
    heard = {o.clip.path.name: o.heard for o in fit.outcomes(dataset(), v, d)}
    assert heard["bad-as-back.wav"] == []
    figures = fit.figures(fit.outcomes(dataset(), v, d), VOCABULARY)
    assert figures["every held-out voice"]["other kind"]["heard"] == 0


def test_the_targets_table_counts_the_phrases_under_the_target():
    v = next(x for x in fit.VARIANTS if x.name == "scorer + sound-alikes")
    d = fit.fit_variant(dataset(), v, VOCABULARY)
    outs = fit.outcomes(dataset(), v, d)
    every = fit.figures(outs, VOCABULARY)["every held-out voice"]
    assert every["phrases under 0.80"] == ["bad"] and every["phrases"] == 2
    assert list(every["worst words"]) == ["bad", "good"]  # the worst first, ties by name
    table = fit.markdown("x", {"decision": {"accept": 0.5, "kind_margin": 2.0}, "held-out": {
        "every held-out voice": every, "recorded": {"unrelated": [0.0, 3]}}})  # fmt: skip
    assert "| every held-out voice |" in table and "| 1 of 2 |" in table
    assert table.count("|---") == 10  # the header's columns, every row as many
    assert all(r.count("|") == 11 for r in table.splitlines() if r.startswith("|"))


def test_pocketsphinx_alone_and_the_cascade_decide_as_the_engines_do():
    said = clip("perfect", "vocabulary")
    sure = row(said, "perfect", SURE, ps=["perfect", 0.9])
    cascade = next(x for x in fit.VARIANTS if x.name == "cascade")
    rule = fit.fit_variant(dataset(), cascade, VOCABULARY)
    (heard, confidence), took = fit.decide(sure, cascade, rule)
    assert heard == "perfect" and confidence >= rule.accept and took == pytest.approx(0.11)
    alone = next(x for x in fit.VARIANTS if not x.scorer)
    assert fit.decide({**sure, "pocketsphinx": ["perfect", 0.5]}, alone, rule) == (
        ("perfect", 0.80),
        0.01,
    )


def test_a_candidate_model_that_is_not_what_it_should_be_is_refused(monkeypatch, tmp_path):
    parts = tmp_path / "parts"
    parts.mkdir()
    for name in (
        "model.bin.part1",
        "model.bin.part2",
        "tokenizer.json",
        "config.json",
        "vocabulary.txt",
    ):
        (parts / name).write_bytes(b"not whisper")
    monkeypatch.setattr(models, "_package", lambda name: parts)
    with pytest.raises(models.ModelError, match=r"model.bin.*SHA-256.*--force-reinstall"):
        models.whisper_base(tmp_path / "cache")
    monkeypatch.setattr(models.importlib.util, "find_spec", lambda name: None)
    monkeypatch.undo()
    monkeypatch.setattr(models.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(models.ModelError, match=r"pip install -e '\.\[whisper-base\]'"):
        models.whisper_base(tmp_path / "elsewhere")


def test_a_candidate_model_not_installed_names_its_setup_step(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(models, "MOONSHINE_TINY", tmp_path / "absent")
    assert models.main(["moonshine-tiny"]) == 1
    assert "setup-voices.sh --moonshine-tiny" in capsys.readouterr().err

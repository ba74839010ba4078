"""The mock speech engine: deterministic for a seed, its error rate and confusion as set,
words outside the vocabulary refused, results out when their latency is due."""

from __future__ import annotations

import dataclasses
from collections import Counter

import numpy as np
import pytest

from tests.test_speech import VOCABULARY
from voxshape.protocol import Said, Utterance
from voxshape.services.speech.mock import MockRecognizer, MockSettings
from voxshape.services.speech.transcriber import MockTranscriber


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

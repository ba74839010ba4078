"""Spanish heard with the English model: words spelt in its phones by rule."""

from __future__ import annotations

from pathlib import Path

import pytest

from voxshape.protocol import load_vocabulary
from voxshape.runtime.audio import read_wav
from voxshape.services.speech.pocketsphinx_engine import PocketsphinxRecognizer
from voxshape.services.speech.spanish import phones, pronunciations, spoken_forms

FIXTURES = Path(__file__).parent / "fixtures" / "speech"


@pytest.mark.parametrize(
    ("word", "expected"),
    [
        ("izquierda", "IY S K Y EH R D AA"),  # qu is K, i before a vowel a glide
        ("derecha", "D EH R EH CH AA"),
        ("llegaste", "Y EH G AA S T EH"),  # ll is Y
        ("excelente", "EH K S EH L EH N T EH"),  # x is K S, c before e is S: one S
        ("hacia", "AA S Y AA"),  # h is silent
        ("gira", "HH IY R AA"),  # g before i is HH
        ("sigue", "S IY G EH"),  # gu before e is G
        ("atrás", "AA T R AA S"),  # accents read as the plain vowel
        ("muy", "M UW IY"),  # a final y is a vowel
        ("avanzar", "AA B AA N S AA R"),  # v is B, z is S
    ],
)
def test_spanish_words_are_spelt_in_english_phones_by_rule(word, expected):
    assert " ".join(phones(word)) == expected


def test_variants_offer_the_english_vowels_a_model_may_hear():
    assert pronunciations("mal") == [("M", "AA", "L"), ("M", "AH", "L"), ("M", "AE", "L")]
    assert spoken_forms("gira a la derecha") == [
        ("gira", "a", "la", "derecha"),
        ("gira", "la", "derecha"),  # the a merges into gira's
    ]


def test_pocketsphinx_hears_spanish_without_a_spanish_model():
    """The committed Spanish clips, and English words outside the vocabulary, with the
    default install (measured on many more voices in docs/speech.md)."""
    recognizer = PocketsphinxRecognizer(load_vocabulary(), "es")
    heard = {
        clip.name: recognizer.recognize(read_wav(clip))
        for clip in sorted(FIXTURES.glob("es-voc-*.wav"))
    }
    right = [name for name, got in heard.items() if got and got.text in name.replace("-", " ")]
    assert len(heard) == 5 and len(right) >= 4, heard
    outside = [recognizer.recognize(read_wav(c)) for c in sorted(FIXTURES.glob("en-oov-*.wav"))]
    assert sum(got is not None for got in outside) <= 1, outside

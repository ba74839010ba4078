"""What a phrase competes with: its sound-alikes from pocketsphinx's dictionary, free speech
and the other phrases, weighed into a confidence; and phrases spotted inside sentences,
negations refused."""

from __future__ import annotations

import pytest

from voxshape.protocol import load_vocabulary
from voxshape.protocol.vocabulary import spot, written_phrases
from voxshape.services.speech import decision
from voxshape.services.speech.decision import Margins
from voxshape.services.speech.sound_alikes import SoundAlikes, cmudict, one_edit

PHRASES = written_phrases(load_vocabulary(), "en")


@pytest.fixture(scope="module")
def alikes() -> SoundAlikes:
    return SoundAlikes(cmudict())


def test_sound_alikes_are_one_phone_substituted_added_or_dropped(alikes):
    good = alikes.of("good")  # G UH D
    assert {"could", "would", "hood", "wood", "should", "god"} <= set(good)
    assert {"go", "gold", "goat", "bowl", "coal"} <= set(alikes.of("goal"))  # G OW L
    assert "food" not in good  # F UW D: two phones away
    assert "good" not in good and "left" in alikes.of("lift")


def test_homophones_and_dictionary_oddities_are_no_competitors(alikes):
    right = alikes.of("right")
    assert "write" not in right and "rite" not in right  # they sound the same
    assert {"light", "bright", "fight", "rice"} <= set(right)
    assert all(w.isalpha() for w in right)  # no "right's", no "r.i."


def test_a_phrase_competes_with_itself_one_word_changed(alikes):
    assert {"go lift", "go loft", "no left"} <= set(alikes.of_phrase(("go", "left")))


def test_one_edit_counts_each_kind_of_edit():
    near = one_edit(("G", "UH", "D"))
    assert ("K", "UH", "D") in near and ("G", "UH", "D", "Z") in near and ("G", "UH") in near
    assert ("G", "UH", "D") not in near and ("K", "AA", "D") not in near


def test_confidence_grows_with_every_margin_weighed_up_and_with_pocketsphinx():
    weights = (0.1, 0.2, 0.2, 1.9, 0.5, 0.3, 1.0, 0.0, -1.9)
    base = Margins(1.0, 1.0, 1.0)
    for better in (Margins(3, 1, 1), Margins(1, 3, 1), Margins(1, 1, 3), Margins(1, 1, 1, 1, 0.9)):
        assert decision.confidence(better, weights) > decision.confidence(base, weights)
    assert decision.confidence(Margins(1, 1, 1, prior=3), weights) > decision.confidence(
        Margins(1, 1, 1, prior=1), weights
    )
    far = Margins(100.0, 100.0, 100.0, 1.0, 1.0)  # capped: a margin says no more past 8 nats
    assert decision.confidence(far, weights) == decision.confidence(Margins(8, 8, 8, 1, 1), weights)
    assert 0 < decision.confidence(Margins(-50, -50, -50, prior=-50), weights) < 0.01


@pytest.mark.parametrize(
    ("transcript", "spotted"),
    [
        ("could you go left", ("go left", False)),
        ("thats good", ("good", False)),
        ("no good", ("good", True)),
        ("that is not right", ("right", True)),
        ("never go back", ("go back", True)),
        ("not that way", ("not that way", False)),  # a phrase of its own, not a negation
        ("please turn to your left now", ("turn to your left", False)),
        ("i could use some food", (None, False)),
        ("left", (None, False)),  # one word is the whole-utterance decision's
    ],
)
def test_a_phrase_is_spotted_in_a_sentence_unless_negated(transcript, spotted):
    assert spot(transcript, PHRASES) == spotted


def test_a_judgement_is_never_taken_for_a_command_without_a_wide_margin():
    d = decision.DecisionRule((0.5, 0.5, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), 0.7, kind_margin=4.0)
    sure = Margins(6.0, 6.0, 6.0, other_kind=6.0)
    assert decision.choose([("back", sure)], d) == ("back", decision.confidence(sure, d.weights))
    close = Margins(6.0, 6.0, 6.0, other_kind=2.0)  # "bad" was within 2 nats of "back"
    assert decision.choose([("back", close)], d) is None
    unsure = Margins(0.0, 0.0, 0.0, other_kind=8.0)
    assert decision.choose([("back", unsure)], d) is None
    assert decision.choose([("back", unsure), ("bad", sure)], d)[0] == "bad"  # type: ignore[index]
    assert decision.kind_of("goal") == decision.kind_of("qualifier") != decision.kind_of("command")
    kinds = {"back": "command", "bad": "judgement"}
    ears_disagree = [("back", sure), ("bad", Margins(0.0, 0.0, 0.0, 1.0, 0.9))]
    assert decision.choose(ears_disagree, d, kinds) is None  # pocketsphinx heard "bad"

"""The arbiter's core without the bus: what words mean (both languages, confidence), and
how teachers' judgements merge. Times are made up and exact."""

from __future__ import annotations

import pytest

from tests.arbiter_support import T0, VOCABULARY, arbiter, credits, feedback, notices, shown
from voxshape.protocol import (
    TeachingStats,
)
from voxshape.protocol.vocabulary import parse_vocabulary
from voxshape.services.arbiter.arbiter import Arbiter
from voxshape.services.arbiter.config import (
    ArbiterConfig,
    ArbiterConfigError,
    DelayLearning,
)
from voxshape.services.arbiter.scripted import (
    scripted_observation,
    scripted_utterance,
)


@pytest.mark.parametrize(
    ("text", "kind", "expected"),
    [
        ("muy bien", "reward", 50.0),
        ("¡Sigue así!", "reward", 10.0),
        ("Por ahí no", "reward", -10.0),
        ("keep going", "reward", 10.0),
        ("NOT LIKE THAT.", "reward", -50.0),
        ("objetivo", "reward", 100.0),
        ("gira a la izquierda", "command", "left"),
        ("go to your right", "command", "right"),
        ("para ahí", "command", "stop"),
    ],
)
def test_words_and_phrases_of_both_languages(text, kind, expected):
    a = arbiter()
    (fb,) = feedback(a.on_utterance(scripted_utterance("ana", "r1", text, shown(90)), shown(99)))
    assert fb.kind == kind
    assert (fb.reward if kind == "reward" else fb.command) == expected


@pytest.mark.parametrize(
    "text", ["banana", "muy banana", "go sideways", "izquierda derecha", "?!", "gira"]
)
def test_unknown_words_and_phrases_are_ignored_and_the_teacher_asked_to_repeat(text):
    a = arbiter()
    out = a.on_utterance(scripted_utterance("ana", "r1", text, shown(90)), shown(99))
    assert not feedback(out)
    (notice,) = notices(out)
    assert notice.kind == "not_understood" and notice.text.startswith(
        f"not understood: {text!r} is not in the vocabulary; say e.g. "
    )
    assert a.counters["rejected.not_understood"] == 1


def test_low_confidence_is_ignored_and_the_teacher_asked_to_repeat():
    a = arbiter(min_confidence=0.6)
    out = a.on_utterance(
        scripted_utterance("ana", "r1", "good", shown(90), confidence=0.59), shown(99)
    )
    (notice,) = notices(out)
    assert not feedback(out) and notice.kind == "low_confidence"
    assert notice.text == (
        "not used: heard 'good' with confidence 0.59, below 0.60; say it again, clearly"
    )
    assert feedback(
        a.on_utterance(
            scripted_utterance("ana", "r1", "good", shown(90), confidence=0.6), shown(99)
        )
    )


def test_a_command_is_credited_to_the_steps_the_teacher_saw_when_deciding_it():
    """The learner carries a command out at once, and takes it as a word about the way from
    where the robot was when the teacher decided it: the steps a judgement said then would
    be credited to."""
    a = arbiter(learning=DelayLearning(enabled=False))  # TAMER's 0.2-0.8 s window
    out = a.on_utterance(scripted_utterance("ana", "r1", "avanza", shown(50) + 0.55), shown(99))
    (fb,) = feedback(out)
    assert (fb.kind, fb.command, fb.reward) == ("command", "forward", None)
    assert set(credits(fb)) == set(range(47, 54))
    assert sum(credits(fb).values()) == pytest.approx(1.0, abs=1e-5)


def test_rewards_are_merged_unbounded_the_learner_bounds_them_by_g():
    """One bound of g, the learner's feedback_bound (test_learner.py): the arbiter does not
    clip, and refuses teacher weights that could take a reward out of the message's range."""
    loud = parse_vocabulary(
        {"version": 1, "huge": {"kind": "qualifier", "reward": 500.0, "en": ["amazing"]}}
    )
    a = Arbiter(ArbiterConfig(teacher_weight={"bob": 3.0}), loud)
    a.on_observation(scripted_observation("r1", 0, T0), T0)
    (fb,) = feedback(a.on_utterance(scripted_utterance("ana", "r1", "amazing", T0 + 0.5), T0 + 1))
    assert fb.reward == 500.0
    with pytest.raises(ArbiterConfigError, match="within \\[0, 100\\]"):
        ArbiterConfig(teacher_weight={"bob": 1000.0})


def judge_same_steps(a: Arbiter, *said: tuple[str, str]) -> list:
    out = []
    for i, (teacher, text) in enumerate(said):
        out += a.on_utterance(
            scripted_utterance(teacher, "r1", text, shown(60) + 0.01 * i), shown(99)
        )
    return out


def test_sum_sends_each_teacher_at_once_and_conflicts_cancel_in_the_learner():
    a = arbiter()
    out = feedback(judge_same_steps(a, ("ana", "good"), ("bob", "bad")))
    assert [f.reward for f in out] == [10.0, -10.0]
    assert a.agreement.compared["r1", "ana"] == 1 and a.agreement.share("r1", "ana") == 0.0


def test_mean_merges_conflicting_teachers_by_weight_after_the_window():
    a = arbiter(merge="mean", merge_window=1.0, teacher_weight={"ana": 3.0})
    assert not feedback(judge_same_steps(a, ("ana", "good"), ("bob", "bad")))
    assert not feedback(a.on_tick(shown(99) + 0.5))
    (fb,) = feedback(a.on_tick(shown(99) + 1.0))
    assert fb.reward == pytest.approx((3 * 10 - 10) / 4)
    assert set(fb.teachers) == {"ana", "bob"} and len(fb.sources) == 2
    assert abs(sum(c.weight for c in fb.credits) - 1) < 1e-6


def test_majority_keeps_the_heavier_side_and_drops_a_tie():
    a = arbiter(merge="majority")
    judge_same_steps(a, ("ana", "good"), ("bob", "bad"), ("cy", "excellent"))
    (fb,) = feedback(a.on_tick(shown(99) + 1.0))
    assert fb.reward == pytest.approx(30.0) and set(fb.teachers) == {"ana", "cy"}
    tie = arbiter(merge="majority")
    judge_same_steps(tie, ("ana", "good"), ("bob", "bad"))
    assert not feedback(tie.on_tick(shown(99) + 1.0))
    assert tie.merger.counters["conflict_tie"] == 1


def test_judgements_about_different_steps_are_not_merged():
    a = arbiter(merge="mean")
    a.on_utterance(scripted_utterance("ana", "r1", "good", shown(20)), shown(99))
    a.on_utterance(scripted_utterance("bob", "r1", "bad", shown(70)), shown(99))
    assert sorted(f.reward for f in feedback(a.on_tick(shown(99) + 1.0))) == [-10.0, 10.0]


def test_per_teacher_statistics_and_interventions_per_episode():
    a = Arbiter(ArbiterConfig(settle=3.0), VOCABULARY)
    for k in range(30):
        end = k == 19
        episode = 0 if k <= 19 else 1
        obs = scripted_observation(
            "r1", k, shown(k), episode=episode, outcome="goal" if end else "running"
        )
        a.on_observation(obs, shown(k))
        if k == 15:
            a.on_utterance(scripted_utterance("ana", "r1", "good", shown(14)), shown(k))
            a.on_utterance(scripted_utterance("ana", "r1", "banana", shown(14)), shown(k))
            a.on_utterance(scripted_utterance("bob", "r1", "left", shown(14)), shown(k))
    live = [m for m in a.on_tick(shown(29)) if isinstance(m, TeachingStats)]
    assert [(s.episode, s.final) for s in live] == [(1, False)]
    assert not [m for m in a.on_tick(shown(19) + 2.9) if isinstance(m, TeachingStats)]
    (final,) = [m for m in a.on_tick(shown(19) + 3.0) if isinstance(m, TeachingStats)]
    assert (final.episode, final.final, final.interventions) == (0, True, 2)
    ana = next(t for t in final.teachers if t.teacher == "ana")
    assert (ana.utterances, ana.understood, ana.ignored, ana.interventions) == (2, 1, 1, 1)
    assert ana.delay == pytest.approx(0.5) and not ana.delay_learned and ana.clock_offset is None

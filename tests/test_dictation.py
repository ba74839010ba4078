"""Traces a person could dictate: commands held until the next, said late, on a budget, heard
with errors, and what they cost counted."""

from __future__ import annotations

import itertools
import math

import pytest

from voxshape.lab.experiment.dictation import dictate
from voxshape.lab.experiment.inprocess import RunSpec, run
from voxshape.protocol.vocabulary import load_vocabulary
from voxshape.services.learner.config import LearnerConfig
from voxshape.services.simteacher.dictating import DictatingPerson, DictationProfile
from voxshape.world.geodesic import GeodesicDistance
from voxshape.world.maps import load_map

VOCABULARY = load_vocabulary()
VELOCITIES = LearnerConfig().velocities


def person(profile: DictationProfile, task: str = "1", seed: int = 0) -> DictatingPerson:
    return DictatingPerson(load_map(task), VOCABULARY, profile, VELOCITIES, seed)


def test_a_person_speaks_late_once_a_word_has_been_said_and_within_the_budget():
    p = person(DictationProfile(words_per_robot_minute=20, words_at_once=2))
    said = []
    # a robot at the start of task 1, facing away from the goal, turning on the spot forever
    for step in range(1200):  # two robot minutes
        now = step * 0.1
        theta = math.remainder(math.pi + now, math.tau)
        word = p.watch(now, 1.0, 1.0, theta, 0.0, 1.0, "stop")
        if word is not None:
            said.append((now, word))
    assert p.words == len(said) <= 20 * 2 + 2  # the budget: 20 a robot minute, 2 at once
    for (now, word), (later, _) in itertools.pairwise(said):
        # heard 0.5-1.5 s (reaction) + 0.4 s (speaking) + 0.3 s (recognition) after seeing
        assert 1.2 - 1e-9 <= word.heard_at - now <= 2.2 + 1e-9
        assert later >= word.heard_at - 0.3 - 1e-9  # the next word once this one was said


def test_a_noisy_person_is_misheard_as_often_as_asked():
    p = person(DictationProfile(noise=0.5, words_per_robot_minute=1e6, words_at_once=1e6))
    wrong = 0
    for step in range(4000):
        word = p.watch(step * 10.0, 1.0, 1.0, math.pi, 0.0, 0.0, "stop")  # way: the left turn
        wrong += word is not None and word.heard != word.meant
    assert p.words == 4000 and wrong / 4000 == pytest.approx(0.5, abs=0.03)


@pytest.mark.parametrize("task", ["1", "4"])
def test_dictated_traces_reach_the_goal_a_turn_then_on_forward_until_the_next_word(task):
    m = load_map(task)
    dictation = dictate(m, 1, seed=1)
    (episode,) = dictation.book.episodes
    assert episode[-1][0].outcome == "goal"
    commands = [d.discrete for _, d in episode if d is not None and d.chooser == "teacher"]
    changes = sum(a != b for a, b in itertools.pairwise(commands))
    assert changes < 2 * dictation.words  # a word: its turn, then forward held
    assert dictation.words <= 20 * dictation.seconds / 60 + 2  # 20 a robot minute
    assert dictation.seconds == pytest.approx(len(episode) * 0.1 - 0.1, abs=1e-6)
    # near the shortest way: within 6x its time at 0.5 m/s, though every word is late
    shortest = GeodesicDistance(m)(m.start.x, m.start.y) / 0.5
    assert dictation.seconds < 6 * shortest


def test_traces_are_dictated_with_the_actions_of_the_learner_that_learns_from_them():
    m = load_map("1")
    on_the_spot = {**VELOCITIES, "left": (0.0, 1.0), "right": (0.0, -1.0)}
    arcs = dictate(m, 1, seed=1).book
    spot = dictate(m, 1, seed=1, config=LearnerConfig(velocities=on_the_spot)).book
    turns = [d for _, d in spot.episodes[0] if d is not None and d.omega]
    assert turns and all(d.v == 0.0 for d in turns)
    assert all(d.v > 0 for _, d in arcs.episodes[0] if d is not None and d.omega)


def test_a_run_counts_the_dictation_in_its_robot_time_and_words():
    result = run(RunSpec("1", "rl+t", 0, max_episodes=2))
    assert result.dictation_s > 0 and result.dictation_words > 0
    assert result.interventions == 0  # no words while it learns: traces alone
    assert result.robot_time_s == result.learning_time_s + result.dictation_s
    assert result.words == result.dictation_words

"""The way the robot believes in (way.py) and what a person's words do to it (words.py): a
word that agrees with the guess changes nothing, a lone slip does not turn it, words that
contradict it where it stalls the robot do; each kind of word is credited to what it is about."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import replace

import numpy as np
import pytest

from tests.learner_support import EXACT, FORWARD, WALL_LEFT, P
from voxshape.services.learner import checkpoint
from voxshape.services.learner.potential import StraightLine
from voxshape.services.learner.sarsa import Learner
from voxshape.services.learner.way import STALL_AFTER_S, Way
from voxshape.services.learner.words import WordCredit
from voxshape.world.robot import CONTROL_PERIOD_S

GUESS = replace(EXACT, potential="straight_line", potential_scale=10.0, representation="keys")
GOAL = (10.0, 0.0)  # east of every place below: the guess says "east"
EAST, NORTH = np.array([1.0, 0.0]), np.array([0.0, 1.0])


def way(**settings: float) -> Way:
    return Way(StraightLine(GOAL), replace(GUESS, **settings))


def words_on(
    w: Way, poses: list[tuple[float, float, float]], bumped: int | None = None
) -> WordCredit:
    """A WordCredit that saw the robot at these poses, a step each (bumping at step `bumped`)."""
    words = WordCredit(w.config, w, Counter())
    for step, pose in enumerate(poses):
        words.saw(step, pose, step == bumped)
    return words


def northwards(steps: int = 20) -> list[tuple[float, float, float]]:
    return [(2.0, 0.05 * i, math.pi / 2) for i in range(steps)]  # 0.5 m/s north


def test_without_words_the_progress_is_the_guess_own_rise():
    w = way()
    for there in [(3.0, 0.0), (2.0, 1.0), (1.5, -0.5)]:
        assert w.progress((2.0, 0.0), there) == pytest.approx(w.phi(there) - w.phi((2.0, 0.0)))


def test_a_word_that_agrees_with_the_guess_leaves_no_vote():
    w = way()
    eastwards = [(2.0 + 0.05 * i, 0.0, 0.0) for i in range(20)]
    words = words_on(w, eastwards)
    assert words.judged(step=19, weight=1.0, f=10.0)  # "good" on what the guess praises too
    assert not w.votes and words.counters["votes_agreeing"] == 1


def test_a_lone_slip_does_not_turn_the_way_but_words_where_the_guess_stalls_do():
    w = way()
    here = (2.0, 0.0)
    w.vote(here, -EAST, 1.0)  # one "bad" about going east: a slip, the guess says east
    assert w.progress(here, (2.5, 0.0)) == pytest.approx(w.phi((2.5, 0.0)) - w.phi(here))
    w.vote(here, NORTH, 1.0)  # and a word for north: 1 vote each against kappa = 3
    assert w.progress(here, (2.0, 0.5)) < w.progress(here, (2.5, 0.0))  # the guess stands
    for _ in range(round(60 / CONTROL_PERIOD_S)):  # a minute there without progress
        w.watch(here, CONTROL_PERIOD_S, new_episode=False)
    assert w.kappa(here) < 0.5  # the guess has stalled the robot here: it weighs less
    assert w.progress(here, (2.0, 0.5)) > 0 > w.progress(here, (2.5, 0.0))  # north now
    assert w.kappa((9.0, 5.0)) == GUESS.guess_weight  # elsewhere the guess stands


def test_the_guess_stalls_only_once_it_has_not_risen_for_a_while():
    w = way()
    w.watch((2.0, 0.0), CONTROL_PERIOD_S, new_episode=True)  # its best so far
    for _ in range(round(STALL_AFTER_S / CONTROL_PERIOD_S) - 1):
        w.watch((2.0, 0.0), CONTROL_PERIOD_S, new_episode=False)
    assert not w.stalled  # not yet
    w.watch((2.0, 0.0), CONTROL_PERIOD_S, new_episode=False)
    assert w.stalled


def test_a_judgement_votes_on_the_motion_it_judges_against_the_guess():
    w = way()
    words = words_on(w, northwards())
    assert words.judged(step=19, weight=0.5, f=10.0)  # "good" on going north: news
    middle = (2.0, 0.7)  # of the judged second, 0.45 m to 0.95 m north
    assert w.W(middle) @ NORTH == pytest.approx(0.5)  # by the arbiter's weight
    assert words.judged(step=19, weight=1.0, f=-50.0)  # "terrible": the guess agrees
    assert w.W(middle) @ NORTH == pytest.approx(0.5) and words.counters["votes_agreeing"] == 1


def test_a_judgement_of_a_robot_stuck_or_bumping_says_nothing_of_the_way():
    w = way()
    standing = [(2.0, 0.0, math.pi / 2)] * 20
    assert words_on(w, standing).judged(step=19, weight=1.0, f=-10.0)
    bumping = words_on(w, northwards(), bumped=15)
    assert bumping.judged(step=19, weight=1.0, f=-10.0)
    assert not w.votes and bumping.counters["votes_stuck"] == 1


def test_a_word_about_a_step_that_left_the_window_is_dropped():
    w = way(feedback_window_s=1.0)
    words = words_on(w, northwards(40))  # 4 s: the first 3 s have left the window
    assert not words.judged(step=5, weight=1.0, f=10.0)
    assert words.commanded("left", [(5, 1.0)]) == [5] and not words.answered(5, "left")
    assert not w.votes


@pytest.mark.parametrize(
    ("command", "heading"), [("left", math.pi), ("right", 0.0), ("forward", math.pi / 2)]
)
def test_a_command_votes_for_the_heading_it_asks_for_where_the_person_saw_the_robot(
    command, heading
):
    w = way()
    words = words_on(w, northwards())
    assert words.commanded(command, [(5, 0.25), (5, 0.75)]) == []
    vote = w.W(words.pose_at(5)[:2])
    assert math.atan2(vote[1], vote[0]) == pytest.approx(math.remainder(heading, math.tau))
    assert np.hypot(*vote) == pytest.approx(1.0)  # the weights of its credits add to one
    assert words.commanded("stop", [(5, 1.0)]) == []  # "stop" says nothing of the way


def test_a_way_shown_votes_along_it_for_the_way_on_but_not_before_a_bump():
    w = way()
    words = WordCredit(w.config, w, Counter())
    path = [(0.05 * i, 0.0, False) for i in range(60)] + [(3.0, 0.05 * i, False) for i in range(60)]
    path[110] = (*path[110][:2], True)
    words.shown(path)
    assert w.W((0.5, 0.0)) @ EAST > 0.5  # eastwards where it went east
    assert w.W((3.0, 1.0)) @ NORTH > 0.5  # northwards after its turn
    assert words.counters["votes_shown"] < len(np.arange(0, 6.0, 0.5))  # none near the bump


def test_votes_and_stalls_fade_each_episode_so_the_robot_takes_over():
    w = way(word_fade=0.5)
    w.vote((2.0, 0.0), NORTH, 1.0)
    for _ in range(round(30 / CONTROL_PERIOD_S)):
        w.watch((2.0, 0.0), CONTROL_PERIOD_S, new_episode=False)
    stalled = sum(w.stalled.values())
    w.fade()
    assert w.W((2.0, 0.0)) @ NORTH == pytest.approx(0.5)
    assert sum(w.stalled.values()) == pytest.approx(stalled / 2)


def test_the_words_correction_of_the_way_enters_the_update():
    learner = Learner(replace(GUESS, stall_s=0.0, guess_weight=1.0), seed=0)
    learner.way.guess.goal = GOAL
    for _ in range(3):
        learner.way.vote((2.0, 0.0), NORTH, 1.0)  # the way north, against the guess
    forward = learner.actions.one_hot(FORWARD)
    learner.step(P(WALL_LEFT, x=2.0, y=0.0, goal_distance=8.0, step=0), forced=forward)
    before = learner.Q.copy()
    learner.step(P(WALL_LEFT, x=2.0, y=0.5, goal_distance=8.0, step=1), forced=forward)
    shaped = learner.Q - before
    alone = Learner(GUESS, seed=0)  # no words: F is the guess's alone
    alone.way.guess.goal = GOAL
    alone.step(P(WALL_LEFT, x=2.0, y=0.0, goal_distance=8.0, step=0), forced=forward)
    alone.step(P(WALL_LEFT, x=2.0, y=0.5, goal_distance=8.0, step=1), forced=forward)
    assert shaped[0, FORWARD] > alone.Q[0, FORWARD]  # going north earned the words' progress


def test_with_no_guess_the_votes_alone_guide_the_lookahead():
    config = replace(EXACT, potential="none", lookahead_weight=1.0, potential_scale=10.0)
    learner = Learner(config, seed=0)
    clear = (8.0,) * 180
    learner.step(P(clear, x=2.0, y=2.0, theta=0.0, step=0))
    assert learner._expected_progress() == 0.0  # nobody spoke: no guidance at all
    learner.way.vote((2.0, 2.0), NORTH, 5.0)
    progress = learner._expected_progress()
    assert progress[3] > progress[FORWARD]  # the left arc heads north


def test_a_checkpoint_keeps_the_way(tmp_path):
    learner = Learner(GUESS, seed=0)
    learner.step(P(WALL_LEFT, x=2.0, y=0.0, step=0))
    learner.way.vote((2.0, 0.0), NORTH, 2.0)
    learner.way.stalled[(0, 1, 0)] = 12.0
    checkpoint.save(learner, tmp_path / "l.npz")
    restored = checkpoint.load(tmp_path / "l.npz", GUESS)
    assert restored.way.W((2.0, 0.0)) @ NORTH == pytest.approx(2.0)
    assert restored.way.stalled == {(0, 1, 0): 12.0}

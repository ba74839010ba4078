"""The simulated teacher's core: what it says, when, how it errs, and the traces it dictates."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import replace

import pytest

from voxshape.protocol.vocabulary import load_vocabulary
from voxshape.services.simteacher.teacher import (
    PERSON,
    PROFILES,
    TIRELESS,
    Confusion,
    FeedbackSchedule,
    Look,
    SimulatedTeacher,
    TeacherProfile,
)
from voxshape.world.geodesic import GeodesicDistance
from voxshape.world.maps import load_map

VOCABULARY = load_vocabulary()
QUIET = replace(TIRELESS, jitter=0.0)  # judges every look, never errs, a steady 0.5 s delay


def teacher(profile: TeacherProfile = QUIET, task: str = "1", seed: int = 0) -> SimulatedTeacher:
    return SimulatedTeacher(load_map(task), VOCABULARY, profile, seed)


def look(t: float, x: float, y: float, **kw: object) -> Look:
    fields = {"episode": 0, "collided": False, "outcome": "running"} | kw
    return Look(t, x=x, y=y, **fields)  # type: ignore[arg-type]


def meanings(speeches: list) -> list[str]:
    return [VOCABULARY.lookup(s.heard).name for s in speeches]


def test_geodesic_distance_goes_around_the_wall():
    m = load_map("4")  # the goal is in the other room, through a door at x = 5
    distance = GeodesicDistance(m)
    behind_the_wall = distance(4.6, 5.3)  # the straight line to the goal crosses the wall
    assert behind_the_wall > math.hypot(m.goal_x - 4.6, m.goal_y - 5.3) + 1.0
    assert behind_the_wall > distance(5.0, 3.0)  # farther than the door itself
    assert distance(m.goal_x, m.goal_y) == 0.0
    assert math.isfinite(distance(4.93, 1.0))  # hugging the wall: the nearest free cell's


@pytest.mark.parametrize(
    ("progress", "meaning"),
    [(0.5, "excellent"), (0.2, "good"), (0.05, None), (-0.05, None), (-0.2, "bad"),
     (-0.5, "terrible")],
)  # fmt: skip
def test_the_size_of_the_change_chooses_the_word(progress, meaning):
    assert teacher().judge(progress) == meaning


def test_it_praises_progress_and_scolds_regress_over_its_interval():
    t = teacher()  # task 1: an open room, the goal up and to the right of the start
    m = t.map
    assert t.watch(look(0.0, 1.0, 1.0)) == []  # the first look: nothing to compare with
    assert t.watch(look(0.5, 1.1, 1.1)) == []  # within the interval: still watching
    toward = t.watch(look(1.0, 1.3, 1.3))  # 0.42 m nearer along the diagonal
    assert meanings(toward) == ["excellent"]
    away = t.watch(look(2.0, 1.15, 1.15))
    assert meanings(away) == ["bad"]
    assert t.watch(look(3.0, 1.15, 1.16)) == []  # about where it was: no comment
    assert meanings(t.watch(look(3.1, 1.15, 1.16, collided=True))) == ["terrible"]  # a bump
    assert t.watch(look(3.2, 1.15, 1.16, collided=True)) == []  # still the same bump
    assert meanings(t.watch(look(3.3, m.goal_x, m.goal_y, outcome="goal"))) == ["goal"]


def test_a_robot_making_no_progress_is_told_bad_at_every_look_until_it_moves_on():
    t = teacher(replace(QUIET, stuck_after=3.0))
    assert meanings(t.watch(look(0.0, 1.0, 1.0))) == []
    said = [meanings(t.watch(look(float(s), 1.0, 1.02))) for s in range(1, 6)]  # pinned
    assert said == [[], [], ["bad"], ["bad"], ["bad"]]  # from 3 s without progress on
    assert meanings(t.watch(look(6.0, 1.3, 1.3))) == ["excellent"]  # going again
    assert meanings(t.watch(look(7.0, 1.3, 1.31))) == []  # only 1 s since that progress
    never = teacher(replace(QUIET, stuck_after=0.0))
    assert all(not never.watch(look(float(s), 1.0, 1.0)) for s in range(10))


def test_a_person_speaks_where_the_course_changes_not_at_every_look():
    t = teacher(replace(QUIET, salient=True))  # task 1: the goal up and to the right
    t.watch(look(0.0, 1.0, 1.0))
    course = [(1.2, 1.2), (1.4, 1.4), (1.6, 1.6), (1.45, 1.45), (1.3, 1.3), (1.5, 1.5)]
    said = [meanings(t.watch(look(1.0 + s, x, y))) for s, (x, y) in enumerate(course)]
    # sets off the right way; keeps going (silence); turns away; keeps away; back on course
    assert said == [["good"], [], [], ["bad"], [], ["good"]]
    # no nearer than its best (1.6, 1.6) for 3 s and more: stuck, said once, not at every look
    pinned = [meanings(t.watch(look(7.0 + s, 1.5, 1.5))) for s in range(6)]
    assert pinned == [["bad"], [], [], [], [], []]
    assert meanings(t.watch(look(13.0, 1.5, 1.5, collided=True))) == ["terrible"]
    near = t.distance.distance  # within near_goal of the goal along the way: "excellent"
    x, y = t.map.goal_x - 1.0, t.map.goal_y - 0.5
    assert near is not None and meanings(t.watch(look(14.0, x, y))) == ["excellent"]
    assert meanings(t.watch(look(15.0, x + 0.3, y))) == []  # said once per episode
    goal = t.watch(look(15.5, t.map.goal_x, t.map.goal_y, outcome="goal"))
    assert meanings(goal) == ["goal"]


def test_a_persons_budget_bounds_the_words_a_minute_bumps_included():
    rate = 4.0
    t = teacher(replace(QUIET, words_per_robot_minute=rate, words_at_once=2.0))
    said = 0
    for s in range(600):  # ten robot minutes of a robot bumping every second
        t.watch(look(2.0 * s, 1.0, 1.0))
        said += len(t.watch(look(2.0 * s + 1.0, 1.0, 1.0, collided=True)))
    assert 10 * rate <= said <= 10 * rate + 2  # the rate, plus the burst at the start
    unbounded = teacher(replace(QUIET, stuck_after=0.0))
    bumps = [unbounded.watch(look(s + 1.0, 1.0, 1.0, collided=s % 2 == 0)) for s in range(20)]
    assert sum(map(len, bumps)) == 10  # without a budget every bump is said


def test_the_budget_refills_with_robot_time_not_in_the_pauses_between_episodes():
    t = teacher(replace(QUIET, words_per_robot_minute=4.0, words_at_once=2.0))
    said = [t.watch(look(1.0 * s, 1.0, 1.0, collided=s % 2 == 1)) for s in range(6)]
    assert sum(map(len, said)) == 2  # the burst, spent on the first two bumps
    # a new episode after a long pause (300 s of the session's clock, no robot time): bumps
    # again, and the budget is as empty as it was
    pause = 300.0
    said = [t.watch(look(pause + s, 1.0, 1.0, episode=1, collided=s % 2 == 1)) for s in range(10)]
    assert sum(map(len, said)) == 0  # 10 robot seconds: 0.67 of a word refilled


def test_a_person_is_the_default_profile_and_the_tireless_teacher_a_named_one():
    assert TeacherProfile() == PERSON == PROFILES["person"]
    assert (PERSON.words_per_robot_minute, PERSON.salient) == (4.0, True)
    assert (TIRELESS.words_per_robot_minute, TIRELESS.salient) == (0.0, False) and PROFILES[
        "tireless"
    ] == TIRELESS
    assert "at most 4 words a robot minute" in PERSON.describe()
    with pytest.raises(ValueError, match="words_per_robot_minute"):
        TeacherProfile(words_per_robot_minute=-1)


def test_turning_on_the_spot_gets_no_comment():
    silent = teacher(replace(QUIET, stuck_after=0.0))
    silent.watch(look(0.0, 1.0, 1.0, heading=-math.pi / 2))
    assert silent.watch(look(1.0, 1.0, 1.0, heading=-math.pi / 2 + 1.0)) == []


def test_a_teacher_with_patience_does_not_repeat_a_judgement_while_nothing_changes():
    t = teacher(replace(QUIET, repeat_after=3.0))
    t.watch(look(0.0, 1.0, 1.0))
    onwards = [
        meanings(t.watch(look(float(s), 1.0 + 0.2 * s, 1.0 + 0.2 * s))) for s in (1, 2, 3, 4)
    ]
    assert onwards == [["good"], [], [], ["good"]]  # again once 3 s have passed
    assert meanings(t.watch(look(5.0, 1.2, 1.2))) == ["terrible"]  # a change: said at once
    assert meanings(t.watch(look(5.1, 1.2, 1.2, collided=True))) == ["terrible"]  # a bump: always
    assert meanings(t.watch(look(5.2, t.map.goal_x, t.map.goal_y, outcome="goal"))) == ["goal"]


def test_words_and_rewards_come_from_the_vocabulary():
    t = teacher()
    for meaning in ("goal", "excellent", "good", "bad", "terrible"):
        heard = VOCABULARY.lookup(t.phrase(meaning))
        assert heard is not None and heard.name == meaning


def test_speech_starts_after_the_reaction_delay_and_is_heard_later():
    profile = replace(QUIET, delay=1.2, speaking=0.4, recognition=0.3)
    t = teacher(profile)
    t.watch(look(10.0, 1.0, 1.0))
    (speech,) = t.watch(look(11.0, 1.3, 1.3))
    assert speech.onset == pytest.approx(12.2)
    assert speech.end == pytest.approx(12.6)
    assert speech.heard_at == pytest.approx(12.9)


def test_feedback_is_permanent_at_first_and_sporadic_later():
    schedule = FeedbackSchedule(permanent=1.0, permanent_episodes=5, fade_episodes=10, sporadic=0.2)
    assert schedule.probability(0) == schedule.probability(4) == 1.0
    assert 0.2 < schedule.probability(8) < 1.0
    assert schedule.probability(14) == pytest.approx(0.2)
    assert schedule.probability(100) == pytest.approx(0.2)
    silent_later = replace(QUIET, schedule=FeedbackSchedule(permanent_episodes=1, sporadic=0.0,
                                                            fade_episodes=1))  # fmt: skip
    t = teacher(silent_later)
    t.watch(look(0.0, 1.0, 1.0, episode=0))
    assert t.watch(look(1.0, 1.3, 1.3, episode=0))
    t.watch(look(5.0, 1.0, 1.0, episode=1))
    assert t.watch(look(6.0, 1.3, 1.3, episode=1)) == []


def steps_toward_and_away(t: SimulatedTeacher, n: int) -> list:
    """n looks, alternately 0.2 m nearer and farther: n - 1 judgements (good, bad, ...)."""
    speeches = []
    for i in range(n):
        d = 0.14 if i % 2 else 0.0
        speeches += t.watch(look(float(i), 1.0 + d, 1.0 + d))
    return speeches


def test_a_positive_bias_leaves_scolding_unsaid():
    fair = meanings(steps_toward_and_away(teacher(), 41))
    assert fair.count("good") == fair.count("bad") == 20
    biased = meanings(steps_toward_and_away(teacher(replace(QUIET, positive_bias=1.0)), 41))
    assert biased == ["good"] * 20


def test_a_wrong_qualifier_is_the_opposite_judgement():
    profile = replace(QUIET, noise=1.0, confusion=Confusion(1.0, misheard=0.0, dropped=0.0))
    speeches = steps_toward_and_away(teacher(profile), 11)
    assert [s.meant for s in speeches] == ["good", "bad"] * 5
    assert meanings(speeches) == ["bad", "good"] * 5
    assert all(s.error == "wrong_qualifier" and s.heard == s.said for s in speeches)


def test_a_misheard_word_is_another_phrase_of_the_vocabulary_with_less_confidence():
    profile = replace(QUIET, noise=1.0, confusion=Confusion(0.0, misheard=1.0, dropped=0.0))
    speeches = steps_toward_and_away(teacher(profile), 41)
    assert all(s.error == "misheard" and s.heard != s.said for s in speeches)
    assert all(VOCABULARY.lookup(s.heard) is not None for s in speeches)
    assert max(s.confidence for s in speeches) < 0.95
    kinds = {VOCABULARY.lookup(s.heard).kind for s in speeches}
    assert "command" in kinds  # a judgement can be heard as a command


def test_a_dropped_word_is_said_and_not_heard():
    profile = replace(QUIET, noise=1.0, confusion=Confusion(0.0, misheard=0.0, dropped=1.0))
    speeches = steps_toward_and_away(teacher(profile), 11)
    assert len(speeches) == 10 and all(s.error == "dropped" and s.heard == "" for s in speeches)


def test_the_default_errors_are_the_persons_slips_and_the_engines_drops():
    speeches = steps_toward_and_away(teacher(replace(QUIET, noise=0.28)), 2001)
    share = Counter(s.error for s in speeches)
    assert 0.08 < share["wrong_qualifier"] / len(speeches) < 0.12
    assert 0.14 < share["dropped"] / len(speeches) < 0.20
    assert share["misheard"] / len(speeches) < 0.03


def test_the_noise_rate_is_the_share_of_errors():
    speeches = steps_toward_and_away(teacher(replace(QUIET, noise=0.2)), 1001)
    share = sum(s.error is not None for s in speeches) / len(speeches)
    assert 0.16 < share < 0.24


def test_seeded_and_deterministic():
    profile = replace(QUIET, noise=0.3, positive_bias=0.2)
    first = steps_toward_and_away(teacher(profile, seed=7), 200)
    again = steps_toward_and_away(teacher(profile, seed=7), 200)
    other = steps_toward_and_away(teacher(profile, seed=8), 200)
    assert first == again
    assert first != other


def test_the_bus_teacher_takes_a_persons_budget_from_its_command_line():
    from voxshape.cli import parser
    from voxshape.runtime import ConfigError
    from voxshape.services.simteacher.node import profile_from

    person = profile_from(parser().parse_args(["sim-teacher"]))
    assert person == replace(PERSON, confusion=person.confusion)
    chatty = profile_from(
        parser().parse_args(
            ["sim-teacher", "--set", "words_per_robot_minute=8", "--set", "salient=false"]
        )
    )
    assert (chatty.words_per_robot_minute, chatty.salient) == (8.0, False)
    assert chatty.schedule == PERSON.schedule
    tireless = profile_from(parser().parse_args(["sim-teacher", "--teacher-profile", "tireless"]))
    assert tireless == replace(TIRELESS, confusion=tireless.confusion)
    with pytest.raises(ConfigError, match="words_per_robot_minute >= 0"):
        profile_from(parser().parse_args(["sim-teacher", "--set", "words_per_robot_minute=-1"]))
    with pytest.raises(ConfigError, match="KEY is one of"):
        profile_from(parser().parse_args(["sim-teacher", "--set", "rate=2"]))
    noisy = profile_from(parser().parse_args(["sim-teacher", "--noise", "0.2"]))
    assert noisy.noise == 0.2
    with pytest.raises(ConfigError, match="noise has a flag of its own: --noise"):
        profile_from(parser().parse_args(["sim-teacher", "--set", "noise=0.2"]))


def said_along(t: SimulatedTeacher, start: float, step: float, heading: float) -> list[list[str]]:
    """What t says, a look a second for 9 s, of a robot driving diagonally from (start, start)."""
    return [meanings(t.watch(look(s, start + step * s, start + step * s, heading=heading)))
            for s in range(9)]  # fmt: skip


def test_a_steering_person_turns_back_a_robot_that_keeps_heading_away():
    steering = replace(QUIET, steer_after=2.0, stuck_after=0.0)  # task 1: the goal at (5, 5)
    away, toward = math.atan2(-1, -1), math.atan2(1, 1)
    # off the way from its second look (1 s) on: the turn back 2 s later, then every 2 s
    said = said_along(teacher(steering), 2.5, -0.1, away)
    assert said[:7] == [[], ["bad"], ["bad"], ["left"], ["bad"], ["left"], ["bad"]]
    for t, start, step, heading in [
        (teacher(steering), 1.0, 0.1, toward),  # along the way: never steered
        (teacher(replace(steering, steer_after=0.0)), 2.5, -0.1, away),  # a judging person
    ]:
        assert not {"left", "right"} & {
            m for said in said_along(t, start, step, heading) for m in said
        }


def test_a_steering_person_says_the_way_round_at_a_bump_facing_away_else_terrible():
    t = teacher(replace(QUIET, steer_at_bumps=True))
    away, toward = math.atan2(-1, -1), math.atan2(1, 1)
    t.watch(look(0.0, 2.0, 2.0, heading=away))
    assert meanings(t.watch(look(1.0, 2.0, 2.0, heading=away, collided=True))) == ["left"]
    t.watch(look(2.0, 2.0, 2.0, heading=toward))
    assert meanings(t.watch(look(3.0, 2.0, 2.0, heading=toward, collided=True))) == ["terrible"]


def test_the_person_steers_by_default_the_judging_person_is_a_named_profile():
    assert PERSON.steer_after and PERSON.steer_at_bumps and "steering" in PERSON.describe()
    judging = PROFILES["judging"]
    assert not judging.steer_after and not judging.steer_at_bumps
    assert replace(judging, steer_after=PERSON.steer_after, steer_at_bumps=True) == PERSON

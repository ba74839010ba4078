"""The arbiter's core without the bus: clocks and delay credit (what words mean and how
teachers merge: test_arbiter_words.py; hygiene and questions: test_arbiter_hygiene.py). Times
are made up and exact, so the credited steps can be checked by hand."""

from __future__ import annotations

import random
from dataclasses import replace

import pytest

from tests.arbiter_support import PERIOD, T0, VOCABULARY, arbiter, credits, feedback, notices, shown
from voxshape.protocol import (
    ClockProbe,
)
from voxshape.runtime.clock import estimate_from
from voxshape.services.arbiter.arbiter import Arbiter
from voxshape.services.arbiter.clocks import SimulatorClock
from voxshape.services.arbiter.config import (
    ArbiterConfig,
    DelayLearning,
    DelayWindow,
)
from voxshape.services.arbiter.credit import ReactionDelay
from voxshape.services.arbiter.scripted import (
    ScriptedTeacher,
    rehearse,
    scripted_observation,
    scripted_utterance,
    sync_in_process,
)


def test_known_step_timing_and_delay_credit_the_steps_displayed_in_the_window():
    a = arbiter(learning=DelayLearning(enabled=False))  # TAMER's 0.2-0.8 s window
    onset = shown(50) + 0.55  # window: [shown(50) - 0.25, shown(50) + 0.35]
    out = a.on_utterance(scripted_utterance("ana", "r1", "good", onset), received_at=shown(99))
    (fb,) = feedback(out)
    assert fb.kind == "reward" and fb.reward == 10.0 and fb.teachers == ("ana",)
    sixth, twelfth = round(1 / 6, 6), round(1 / 12, 6)
    assert credits(fb) == {
        47: twelfth,
        48: sixth,
        49: sixth,
        50: sixth,
        51: sixth,
        52: sixth,
        53: twelfth,
    }
    assert notices(out)[0].kind == "understood" and notices(out)[0].meaning == "good"


def test_recognition_latency_and_arrival_time_do_not_move_the_credit():
    a, b = arbiter(), arbiter()
    quick = scripted_utterance("ana", "r1", "bad", shown(40))
    slow = replace(quick, recognized_at=quick.onset + 2.5, end=quick.onset + 1.1)
    (fast,) = feedback(a.on_utterance(quick, received_at=shown(41)))
    (late,) = feedback(b.on_utterance(slow, received_at=shown(70)))
    assert credits(fast) == credits(late)


def test_a_teachers_own_window_is_used():
    a = arbiter(teacher_delay={"bob": DelayWindow(1.0, 1.1)}, learning=DelayLearning(enabled=False))
    onset = shown(60) + 1.05 + 0.05  # centre of step 60's display
    (fb,) = feedback(a.on_utterance(scripted_utterance("bob", "r1", "good", onset), shown(99)))
    assert credits(fb) == {60: 1.0}


def test_a_robot_time_teachers_window_is_robot_seconds_at_any_pace():
    """A simulated teacher on a simulator at 20x real time reacts after as many steps as a
    person at real time: its 0.2-0.8 s window covers the same steps as at 10 Hz. A person's
    window stays in their own seconds: 40-160 steps back at that pace."""
    fast = PERIOD / 20
    config = ArbiterConfig(robot_time=frozenset({"sim"}), learning=DelayLearning(enabled=False))
    a = Arbiter(config, VOCABULARY)
    for k in range(400):
        a.on_observation(scripted_observation("r1", k, T0 + k * fast), T0 + k * fast)
    onset = T0 + (300 + 5.5) * fast  # 0.55 robot seconds after step 300 was displayed
    (simulated,) = feedback(
        a.on_utterance(scripted_utterance("sim", "r1", "good", onset), T0 + 399 * fast)
    )
    expected = {297: 1 / 12, **dict.fromkeys(range(298, 303), 1 / 6), 303: 1 / 12}
    assert credits(simulated) == pytest.approx(expected, abs=1e-4)  # 5 ms steps: rounding
    (person,) = feedback(
        a.on_utterance(scripted_utterance("ana", "r1", "good", onset), T0 + 399 * fast)
    )
    assert min(credits(person)) == 145 and max(credits(person)) == 265


def test_a_robot_time_teachers_delay_is_learnt_in_robot_seconds():
    fast = PERIOD / 20
    config = ArbiterConfig(
        utterances_per_s=50.0, utterances_at_once=50.0, robot_time=frozenset({"ana"})
    )
    teacher = ScriptedTeacher("ana", delay=1.2 * fast / PERIOD)  # 1.2 robot s: 60 ms at 20x
    result = rehearse(teacher, steps=3000, period=fast, config=config)
    assert result.learned_after is not None and result.learned_after < 20
    assert result.within_one_step() == 1.0, result.median_error()


def test_terminal_steps_are_never_credited():
    a = Arbiter(ArbiterConfig(learning=DelayLearning(enabled=False)), VOCABULARY)
    for k in range(20):
        end = k == 10
        a.on_observation(
            scripted_observation("r1", k, shown(k), outcome="goal" if end else "running"), shown(k)
        )
    (fb,) = feedback(
        a.on_utterance(scripted_utterance("ana", "r1", "good", shown(10) + 0.5), shown(19))
    )
    assert 10 not in credits(fb) and abs(sum(credits(fb).values()) - 1) < 1e-6


def test_feedback_older_than_the_history_is_too_late_and_the_teacher_is_told():
    a = arbiter(history_seconds=5.0)
    out = a.on_utterance(scripted_utterance("ana", "r1", "good", shown(10)), shown(99))
    assert not feedback(out)
    (notice,) = notices(out)
    assert notice.kind == "too_late" and "too late" in notice.text
    assert a.counters["rejected.too_late"] == 1


@pytest.mark.parametrize("skew", [-5.0, 5.0])
def test_a_skewed_teacher_clock_is_corrected(skew):
    reference = arbiter(learning=DelayLearning(enabled=False))
    skewed = arbiter(learning=DelayLearning(enabled=False))
    estimate, _ = sync_in_process(skewed, ScriptedTeacher("ana", skew=skew), T0, random.Random(1))
    assert abs(estimate.offset - (-skew)) < 0.002  # within the round trip of the exchange
    onset = shown(50) + 0.55
    (want,) = feedback(
        reference.on_utterance(scripted_utterance("ana", "r1", "good", onset), shown(99))
    )
    said = scripted_utterance("ana", "r1", "good", onset + skew)  # the teacher's clock
    (got,) = feedback(skewed.on_utterance(said, shown(99)))
    assert credits(got).keys() == credits(want).keys()
    assert all(abs(credits(got)[s] - w) < 0.02 for s, w in credits(want).items())


def test_without_sync_a_skew_moves_the_credit():
    a = arbiter(learning=DelayLearning(enabled=False))
    (behind,) = feedback(
        a.on_utterance(scripted_utterance("ana", "r1", "good", shown(80) - 5), shown(99))
    )
    assert max(credits(behind)) < 40  # 5 s = 50 steps too early
    (ahead,) = feedback(
        a.on_utterance(scripted_utterance("bob", "r1", "good", shown(80) + 5), shown(99))
    )
    # An onset after its arrival is a clock error: the arrival is the best bound, and counted.
    assert set(credits(ahead)) == set(range(91, 97))
    assert a.counters["onset_after_arrival"] == 1 and a.counters["unsynced_teacher_utterances"] == 2


def test_the_ntp_estimate_and_the_reply():
    a = Arbiter(ArbiterConfig(), VOCABULARY)
    probe = ClockProbe(teacher="ana", t0=100.0, offset=None, rtt=None)
    (reply,) = a.on_clock_probe(probe, received_at=105.010, now=105.011)
    assert (reply.probe, reply.t0, reply.t1, reply.t2) == (probe.id, 100.0, 105.010, 105.011)
    estimate = estimate_from(reply, t3=100.021)  # 10 ms each way, arbiter 5 s ahead
    assert estimate.offset == pytest.approx(5.0) and estimate.rtt == pytest.approx(0.020)
    assert a.clocks.report("ana") is None  # a first probe reports nothing
    a.on_clock_probe(replace(probe, id="0" * 32, offset=5.0, rtt=0.02), 106.0, 106.0)
    assert a.clocks.report("ana").offset == 5.0


def test_the_simulator_clock_is_the_smallest_recent_lag():
    clock = SimulatorClock(window=3)
    for received, wall in [(10.5, 10.0), (11.2, 11.0), (12.3, 12.0), (13.4, 13.0)]:
        clock.observe(received, wall)
    assert clock.offset == pytest.approx(0.2)  # (10.5 - 10.0) slid out of the window
    assert clock.to_sim(20.0) == pytest.approx(19.8)


def test_a_teachers_delay_is_learnt_from_their_reactions_to_bumps():
    teacher = ScriptedTeacher("ana", delay=1.7, skew=5.0)
    learnt = rehearse(teacher, steps=1500)
    tamer = rehearse(teacher, steps=1500, learn=False)
    assert learnt.learned_after is not None and learnt.learned_after < 20
    assert learnt.within_one_step() == 1.0
    assert tamer.within_one_step(after_learning=False) == 0.0  # 0.2-0.8 s is 10 steps off


@pytest.mark.parametrize("delay", [0.0, 0.5, 1.0, 2.0])
@pytest.mark.parametrize("skew", [-5.0, 5.0])
def test_credit_lands_within_one_step_for_delays_up_to_2s_and_skews_of_5s(delay, skew):
    result = rehearse(ScriptedTeacher("ana", delay=delay, skew=skew), steps=1200, seed=3)
    assert result.within_one_step() == 1.0, result.median_error()


def test_the_consensus_ignores_judgements_that_are_not_reactions():
    delay = ReactionDelay(DelayWindow(0.2, 0.8), DelayLearning(min_samples=3))
    rng = random.Random(0)
    for event in range(6):
        delay.add(event, 1.2 + rng.uniform(-0.03, 0.03))  # the reaction
        for _ in range(2):
            delay.add(event, rng.uniform(0.0, 3.0))  # other judgements after the bump
    assert delay.learned
    window = delay.window()
    assert 1.1 < window.lo < window.centre < window.hi < 1.3


def test_delay_is_not_learnt_from_too_few_events_or_when_disabled():
    delay = ReactionDelay(DelayWindow(0.2, 0.8), DelayLearning(min_samples=3))
    delay.add("a", 1.0)
    delay.add("b", 1.0)
    assert not delay.learned and delay.window() == DelayWindow(0.2, 0.8)
    off = ReactionDelay(DelayWindow(0.2, 0.8), DelayLearning(enabled=False))
    for event in "abcd":
        off.add(event, 1.0)
    assert off.window() == DelayWindow(0.2, 0.8)

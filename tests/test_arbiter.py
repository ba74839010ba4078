"""The arbiter's core without the bus: meaning, clocks, delay credit, merging, hygiene,
interventions. Times are made up and exact, so the credited steps can be checked by hand."""

from __future__ import annotations

import random
from dataclasses import replace

import pytest

from voxshape.cli import parser as cli_parser
from voxshape.protocol import (
    ClockProbe,
    CreditedFeedback,
    HelpAnswer,
    HelpRequest,
    TeacherNotice,
    TeachingStats,
)
from voxshape.protocol.vocabulary import load_vocabulary, parse_vocabulary
from voxshape.runtime import ConfigError
from voxshape.runtime.clock import estimate_from
from voxshape.runtime.limits import TokenBucket
from voxshape.services.arbiter.arbiter import Arbiter
from voxshape.services.arbiter.clocks import SimulatorClock
from voxshape.services.arbiter.config import (
    ArbiterConfig,
    ArbiterConfigError,
    DelayLearning,
    DelayWindow,
    parse_window,
)
from voxshape.services.arbiter.credit import ReactionDelay, StepTimeline
from voxshape.services.arbiter.hygiene import RecentIds
from voxshape.services.arbiter.node import config_from
from voxshape.services.arbiter.scripted import (
    ScriptedTeacher,
    observation,
    rehearse,
    sync_in_process,
    utterance,
)

T0 = 1_700_000_000.0  # wall time of step 0
PERIOD = 0.1
VOCABULARY = load_vocabulary()


def shown(step: int) -> float:
    return T0 + step * PERIOD


def arbiter(steps: int = 100, **settings) -> Arbiter:
    """An arbiter that has seen robot r1 step at exactly 10 Hz, steps 0..steps-1."""
    a = Arbiter(ArbiterConfig(**settings), VOCABULARY)
    for k in range(steps):
        a.on_observation(observation("r1", k, shown(k)), shown(k))
    return a


def feedback(messages: list) -> list[CreditedFeedback]:
    return [m for m in messages if isinstance(m, CreditedFeedback)]


def notices(messages: list) -> list[TeacherNotice]:
    return [m for m in messages if isinstance(m, TeacherNotice)]


def credits(message: CreditedFeedback) -> dict[int, float]:
    return {c.step: round(c.weight, 6) for c in message.credits}


# -- delay correction -------------------------------------------------------------------------


def test_known_step_timing_and_delay_credit_the_steps_displayed_in_the_window():
    a = arbiter(learning=DelayLearning(enabled=False))  # TAMER's 0.2-0.8 s window
    onset = shown(50) + 0.55  # window: [shown(50) - 0.25, shown(50) + 0.35]
    out = a.on_utterance(utterance("ana", "r1", "good", onset), received_at=shown(99))
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
    quick = utterance("ana", "r1", "bad", shown(40))
    slow = replace(quick, recognized_at=quick.onset + 2.5, end=quick.onset + 1.1)
    (fast,) = feedback(a.on_utterance(quick, received_at=shown(41)))
    (late,) = feedback(b.on_utterance(slow, received_at=shown(70)))
    assert credits(fast) == credits(late)


def test_a_teachers_own_window_is_used():
    a = arbiter(teacher_delay={"bob": DelayWindow(1.0, 1.1)}, learning=DelayLearning(enabled=False))
    onset = shown(60) + 1.05 + 0.05  # centre of step 60's display
    (fb,) = feedback(a.on_utterance(utterance("bob", "r1", "good", onset), shown(99)))
    assert credits(fb) == {60: 1.0}


def test_a_robot_time_teachers_window_is_robot_seconds_at_any_pace():
    """A simulated teacher on a simulator at 20x real time reacts after as many steps as a
    person at real time: its 0.2-0.8 s window covers the same steps as at 10 Hz. A person's
    window stays in their own seconds: 40-160 steps back at that pace."""
    fast = PERIOD / 20
    config = ArbiterConfig(robot_time=frozenset({"sim"}), learning=DelayLearning(enabled=False))
    a = Arbiter(config, VOCABULARY)
    for k in range(400):
        a.on_observation(observation("r1", k, T0 + k * fast), T0 + k * fast)
    onset = T0 + (300 + 5.5) * fast  # 0.55 robot seconds after step 300 was displayed
    (simulated,) = feedback(a.on_utterance(utterance("sim", "r1", "good", onset), T0 + 399 * fast))
    expected = {297: 1 / 12, **dict.fromkeys(range(298, 303), 1 / 6), 303: 1 / 12}
    assert credits(simulated) == pytest.approx(expected, abs=1e-4)  # 5 ms steps: rounding
    (person,) = feedback(a.on_utterance(utterance("ana", "r1", "good", onset), T0 + 399 * fast))
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
            observation("r1", k, shown(k), outcome="goal" if end else "running"), shown(k)
        )
    (fb,) = feedback(a.on_utterance(utterance("ana", "r1", "good", shown(10) + 0.5), shown(19)))
    assert 10 not in credits(fb) and abs(sum(credits(fb).values()) - 1) < 1e-6


def test_feedback_older_than_the_history_is_too_late_and_the_teacher_is_told():
    a = arbiter(history_seconds=5.0)
    out = a.on_utterance(utterance("ana", "r1", "good", shown(10)), shown(99))
    assert not feedback(out)
    (notice,) = notices(out)
    assert notice.kind == "too_late" and "too late" in notice.text
    assert a.counters["rejected.too_late"] == 1


# -- clocks -----------------------------------------------------------------------------------


@pytest.mark.parametrize("skew", [-5.0, 5.0])
def test_a_skewed_teacher_clock_is_corrected(skew):
    reference = arbiter(learning=DelayLearning(enabled=False))
    skewed = arbiter(learning=DelayLearning(enabled=False))
    estimate, _ = sync_in_process(skewed, ScriptedTeacher("ana", skew=skew), T0, random.Random(1))
    assert abs(estimate.offset - (-skew)) < 0.002  # within the round trip of the exchange
    onset = shown(50) + 0.55
    (want,) = feedback(reference.on_utterance(utterance("ana", "r1", "good", onset), shown(99)))
    said = utterance("ana", "r1", "good", onset + skew)  # the teacher's clock
    (got,) = feedback(skewed.on_utterance(said, shown(99)))
    assert credits(got).keys() == credits(want).keys()
    assert all(abs(credits(got)[s] - w) < 0.02 for s, w in credits(want).items())


def test_without_sync_a_skew_moves_the_credit():
    a = arbiter(learning=DelayLearning(enabled=False))
    (behind,) = feedback(a.on_utterance(utterance("ana", "r1", "good", shown(80) - 5), shown(99)))
    assert max(credits(behind)) < 40  # 5 s = 50 steps too early
    (ahead,) = feedback(a.on_utterance(utterance("bob", "r1", "good", shown(80) + 5), shown(99)))
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


# -- learning each teacher's delay ----------------------------------------------------------


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


# -- meaning ----------------------------------------------------------------------------------


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
    (fb,) = feedback(a.on_utterance(utterance("ana", "r1", text, shown(90)), shown(99)))
    assert fb.kind == kind
    assert (fb.reward if kind == "reward" else fb.command) == expected


@pytest.mark.parametrize(
    "text", ["banana", "muy banana", "go sideways", "izquierda derecha", "?!", "gira"]
)
def test_unknown_words_and_phrases_are_ignored_and_the_teacher_asked_to_repeat(text):
    a = arbiter()
    out = a.on_utterance(utterance("ana", "r1", text, shown(90)), shown(99))
    assert not feedback(out)
    (notice,) = notices(out)
    assert notice.kind == "not_understood" and notice.text.startswith(
        f"not understood: {text!r} is not in the vocabulary; say e.g. "
    )
    assert a.counters["rejected.not_understood"] == 1


def test_low_confidence_is_ignored_and_the_teacher_asked_to_repeat():
    a = arbiter(min_confidence=0.6)
    out = a.on_utterance(utterance("ana", "r1", "good", shown(90), confidence=0.59), shown(99))
    (notice,) = notices(out)
    assert not feedback(out) and notice.kind == "low_confidence"
    assert notice.text == (
        "not used: heard 'good' with confidence 0.59, below 0.60; say it again, clearly"
    )
    assert feedback(
        a.on_utterance(utterance("ana", "r1", "good", shown(90), confidence=0.6), shown(99))
    )


def test_a_command_is_credited_to_the_steps_the_teacher_saw_when_deciding_it():
    """The learner carries a command out at once, and takes it as a word about the way from
    where the robot was when the teacher decided it: the steps a judgement said then would
    be credited to."""
    a = arbiter(learning=DelayLearning(enabled=False))  # TAMER's 0.2-0.8 s window
    out = a.on_utterance(utterance("ana", "r1", "avanza", shown(50) + 0.55), shown(99))
    (fb,) = feedback(out)
    assert (fb.kind, fb.command, fb.reward) == ("command", "forward", None)
    assert set(credits(fb)) == set(range(47, 54))
    assert sum(credits(fb).values()) == pytest.approx(1.0, abs=1e-5)


# -- bounds -----------------------------------------------------------------------------------


def test_rewards_are_merged_unbounded_the_learner_bounds_them_by_g():
    """One bound of g, the learner's feedback_bound (test_learner.py): the arbiter does not
    clip, and refuses teacher weights that could take a reward out of the message's range."""
    loud = parse_vocabulary(
        {"version": 1, "huge": {"kind": "qualifier", "reward": 500.0, "en": ["amazing"]}}
    )
    a = Arbiter(ArbiterConfig(teacher_weight={"bob": 3.0}), loud)
    a.on_observation(observation("r1", 0, T0), T0)
    (fb,) = feedback(a.on_utterance(utterance("ana", "r1", "amazing", T0 + 0.5), T0 + 1))
    assert fb.reward == 500.0
    with pytest.raises(ArbiterConfigError, match="within \\[0, 100\\]"):
        ArbiterConfig(teacher_weight={"bob": 1000.0})


# -- several teachers ---------------------------------------------------------------------------


def judge_same_steps(a: Arbiter, *said: tuple[str, str]) -> list:
    out = []
    for i, (teacher, text) in enumerate(said):
        out += a.on_utterance(utterance(teacher, "r1", text, shown(60) + 0.01 * i), shown(99))
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
    a.on_utterance(utterance("ana", "r1", "good", shown(20)), shown(99))
    a.on_utterance(utterance("bob", "r1", "bad", shown(70)), shown(99))
    assert sorted(f.reward for f in feedback(a.on_tick(shown(99) + 1.0))) == [-10.0, 10.0]


def test_per_teacher_statistics_and_interventions_per_episode():
    a = Arbiter(ArbiterConfig(settle=3.0), VOCABULARY)
    for k in range(30):
        end = k == 19
        episode = 0 if k <= 19 else 1
        obs = observation("r1", k, shown(k), episode=episode, outcome="goal" if end else "running")
        a.on_observation(obs, shown(k))
        if k == 15:
            a.on_utterance(utterance("ana", "r1", "good", shown(14)), shown(k))
            a.on_utterance(utterance("ana", "r1", "banana", shown(14)), shown(k))
            a.on_utterance(utterance("bob", "r1", "left", shown(14)), shown(k))
    live = [m for m in a.on_tick(shown(29)) if isinstance(m, TeachingStats)]
    assert [(s.episode, s.final) for s in live] == [(1, False)]
    assert not [m for m in a.on_tick(shown(19) + 2.9) if isinstance(m, TeachingStats)]
    (final,) = [m for m in a.on_tick(shown(19) + 3.0) if isinstance(m, TeachingStats)]
    assert (final.episode, final.final, final.interventions) == (0, True, 2)
    ana = next(t for t in final.teachers if t.teacher == "ana")
    assert (ana.utterances, ana.understood, ana.ignored, ana.interventions) == (2, 1, 1, 1)
    assert ana.delay == pytest.approx(0.5) and not ana.delay_learned and ana.clock_offset is None


# -- hygiene ----------------------------------------------------------------------------------


def test_duplicates_are_dropped_and_counted():
    a = arbiter()
    said = utterance("ana", "r1", "good", shown(90))
    assert feedback(a.on_utterance(said, shown(99)))
    assert a.on_utterance(said, shown(99)) == []
    assert a.counters["rejected.duplicate"] == 1


def test_a_flood_is_cut_counted_and_the_teacher_told_once():
    a = arbiter(utterances_per_s=4.0, utterances_at_once=8.0)
    out = []
    for i in range(100):  # 100 in one second
        out += a.on_utterance(utterance("ana", "r1", "good", shown(90)), shown(90) + i * 0.01)
    # the burst, then 4/s until 0.4 s in, when each claims to have ended (said at one moment)
    assert len(feedback(out)) == 8 + 1
    limited = [n for n in notices(out) if n.kind == "rate_limited"]
    assert len(limited) == 1 and "slow down" in limited[0].text
    assert a.counters["rejected.rate_limited"] == 100 - len(feedback(out))
    other = a.on_utterance(utterance("bob", "r1", "good", shown(90)), shown(91))
    assert feedback(other)  # another teacher is not limited


def test_a_robot_time_teachers_rate_is_per_robot_second():
    """At 20x real time a simulated teacher saying one thing every robot second says 20 a
    wall second: within its rate in robot seconds. A person saying as much is a flood."""
    fast = PERIOD / 20
    config = ArbiterConfig(robot_time=frozenset({"sim"}), learning=DelayLearning(enabled=False))
    a = Arbiter(config, VOCABULARY)
    for k in range(800):
        a.on_observation(observation("r1", k, T0 + k * fast), T0 + k * fast)
    said = {"sim": 0, "ana": 0}
    for i in range(40):  # one every 10 steps: a robot second, 50 ms of wall time
        at = T0 + (400 + 10 * i) * fast
        for teacher in said:
            said[teacher] += len(feedback(a.on_utterance(utterance(teacher, "r1", "good", at), at)))
    assert said == {"sim": 40, "ana": 8 + 7}  # ana: the burst, then 4/s over 1.95 s


def test_an_unknown_robot_is_rejected_and_the_teacher_told():
    a = arbiter()
    out = a.on_utterance(utterance("ana", "r9", "good", shown(90)), shown(99))
    (notice,) = notices(out)
    assert not feedback(out) and notice.kind == "unknown_robot" and "robots: r1" in notice.text
    quiet = a.on_utterance(utterance("ana", "r1", "good", shown(99)), shown(99) + 60)
    assert notices(quiet)[0].kind == "unknown_robot"  # its simulator went quiet


def test_an_utterance_on_another_teachers_key_is_rejected():
    a = arbiter()
    assert a.on_utterance(utterance("ana", "r1", "good", shown(90)), shown(99), "bob") == []
    assert a.counters["rejected.teacher_mismatch"] == 1


def test_recent_ids_forget_the_oldest_and_buckets_refill():
    ids = RecentIds(capacity=2)
    assert not ids.seen("a") and not ids.seen("b") and ids.seen("a")
    assert not ids.seen("c") and not ids.seen("b")  # b was the least recently seen
    bucket = TokenBucket(rate=2.0, burst=2.0, now=0.0)
    assert [bucket.take(0.0) for _ in range(3)] == [True, True, False]
    assert bucket.take(0.5) and not bucket.take(0.5)
    assert not bucket.take(0.2) and bucket.take(1.0)  # a clock set back refills nothing
    frames = TokenBucket(rate=50.0, burst=50.0)  # full at the start: the web's frame limit
    assert 50 <= sum(frames.take(100.0 + i * 0.001) for i in range(200)) <= 61  # 0.2 s
    audio = TokenBucket(rate=1.0, burst=3.0)  # seconds of audio
    assert audio.take(0.0, 2.5) and not audio.take(0.0, 1.0) and audio.take(0.5, 1.0)


# -- settings ---------------------------------------------------------------------------------


def arbiter_flags(*argv: str, env: dict[str, str] | None = None) -> ArbiterConfig:
    return config_from(cli_parser("arbiter").parse_args(["arbiter", *argv]), env or {})


def test_settings_errors_name_the_problem_and_the_fix():
    assert parse_window("0.3:1.1") == DelayWindow(0.3, 1.1)
    with pytest.raises(ArbiterConfigError, match=r"needs 0 <= lo < hi .* e\.g\. 0\.2:0\.8"):
        parse_window("1:0.5")
    with pytest.raises(ArbiterConfigError, match="is not LO:HI"):
        parse_window("fast")
    with pytest.raises(
        ConfigError, match=r"--teacher-weight 'ana': not TEACHER=VALUE, e\.g\. ana=2"
    ):
        arbiter_flags("--teacher-weight", "ana")
    with pytest.raises(ConfigError, match=r"--teacher-weight 'a/b=2': teacher: .* use 1-64 of"):
        arbiter_flags("--teacher-weight", "a/b=2")
    with pytest.raises(ConfigError, match=r"--delay 'fast': delay window 'fast' is not LO:HI"):
        arbiter_flags("--delay", "fast")
    with pytest.raises(ConfigError, match="VOXSHAPE_MERGE='vote' is not one of sum, mean"):
        arbiter_flags(env={"VOXSHAPE_MERGE": "vote"})
    given = arbiter_flags("--teacher-delay", "ana=0.5:1.2", "--teacher-weight", "bob=3")
    assert given.teacher_delay == {"ana": DelayWindow(0.5, 1.2)}
    assert given.teacher_weight == {"bob": 3.0}
    both = arbiter_flags("--robot-time", "sim", env={"VOXSHAPE_ROBOT_TIME": "ana, bob"})
    assert both.robot_time == {"sim"}  # a flag overrides its variable
    assert arbiter_flags(env={"VOXSHAPE_ROBOT_TIME": "ana, bob"}).robot_time == {"ana", "bob"}
    with pytest.raises(
        ConfigError, match="--set 'merge=mean': merge has a flag of its own: --merge"
    ):
        arbiter_flags("--set", "merge=mean")  # one spelling per setting
    assert arbiter_flags("--set", "settle=5", "--merge", "mean").settle == 5.0
    with pytest.raises(ArbiterConfigError, match="merge policy 'vote'"):
        ArbiterConfig(merge="vote")  # type: ignore[arg-type]


def test_the_step_timeline_is_bounded_and_starts_over_on_a_restart():
    timeline = StepTimeline(history_seconds=1.0, max_steps=5)
    for k in range(50):
        timeline.add(k, shown(k), 0, True)
    assert len(timeline) == 5 and timeline.latest_step == 49
    assert timeline.spread(shown(10), shown(11)) is None  # forgotten: too late
    assert timeline.add(0, shown(60), 0, True) == "restart"  # a restarted simulator
    assert len(timeline) == 1 and timeline.latest_step == 0


def test_recovered_steps_behind_live_ones_go_in_their_place():
    """A restarted arbiter may hear a robot's live steps before its recovered older ones."""
    timeline = StepTimeline(history_seconds=30.0)
    for k in (20, 21):  # live
        assert timeline.add(k, shown(k), 0, True) == "next"
    for k in range(10, 20):  # recovered, late
        assert timeline.add(k, shown(k), 0, True) == "late"
    assert timeline.add(15, shown(15), 0, True) == "late"  # a copy
    assert len(timeline) == 12 and timeline.latest_step == 21
    assert timeline.spread(shown(12), shown(13)).credits == ((12, 1.0),)
    assert timeline.add(5, shown(30), 0, True) == "restart"  # older number, later time
    assert len(timeline) == 1


def test_a_just_started_arbiter_holds_words_for_a_robot_until_it_is_seen():
    """Restarted, it may recover a teacher's utterances before the robot's observations."""
    a = Arbiter(ArbiterConfig(), VOCABULARY, started_at=shown(30))
    said = utterance("ana", "r1", "good", shown(15))  # said before the arbiter started
    assert a.on_utterance(said, shown(30)) == []  # held: r1 not seen yet
    out = []
    for k in range(30):  # recovered: they arrive late, in a burst
        a.on_observation(observation("r1", k, shown(k)), shown(30) + 0.001 * k)
    assert a.on_tick(shown(31)) == []  # still starting
    out = a.on_tick(shown(30) + 3.0)
    assert feedback(out) and notices(out)[0].kind == "understood"
    late = Arbiter(ArbiterConfig(), VOCABULARY, started_at=T0)
    assert late.on_utterance(utterance("ana", "r9", "good", T0 - 1), T0) == []
    (notice,) = notices(late.on_tick(T0 + 3.0))  # nobody came: unknown after the wait
    assert notice.kind == "unknown_robot"
    live = late.on_utterance(utterance("ana", "r8", "good", T0 + 1), T0 + 1)
    assert notices(live)[0].kind == "unknown_robot"  # said after the start: told at once


def test_words_that_arrive_at_once_but_were_said_at_a_pace_are_no_flood():
    """Restarted, it recovers the last seconds of each teacher's words at once; frozen (or
    cut off from the router), it gets what it missed in one go when it is back: 20 here, more
    than the burst of 8, said a second apart. Judged by when they were said, each is
    credited. Words that claim to be said at one moment are still a flood."""
    a = Arbiter(
        ArbiterConfig(utterances_per_s=4.0, utterances_at_once=8.0), VOCABULARY, started_at=shown(0)
    )
    for k in range(300):
        a.on_observation(observation("r1", k, shown(k)), shown(k))
    out = []
    for i in range(20):  # said a word every 10 steps (a second) while it was frozen
        said = utterance("ana", "r1", "good", shown(100 + 10 * i))
        out += a.on_utterance(said, shown(300) + 0.1 + 0.001 * i)
    assert len(feedback(out)) == 20 and a.counters["rejected.rate_limited"] == 0
    at_once = []
    for i in range(20):
        said = utterance("bob", "r1", "good", shown(290))
        at_once += a.on_utterance(said, shown(300) + 0.2 + 0.001 * i)
    assert len(feedback(at_once)) == 8 and a.counters["rejected.rate_limited"] == 12


def test_a_restarted_arbiter_drops_long_recovered_words_before_its_rate_limit():
    """Restarted, it recovers all the speech service kept (256 words a teacher), most said
    long before: those were answered by the arbiter before it, and must not use up the rate
    that the words said during its outage need."""
    a = Arbiter(
        ArbiterConfig(utterances_per_s=4.0, utterances_at_once=8.0),
        VOCABULARY,
        started_at=shown(1000),
    )
    for k in range(700, 1000):  # its recovered observations
        a.on_observation(observation("r1", k, shown(k)), shown(1000) + 0.0001 * k)
    old = [utterance("ana", "r1", "good", shown(k)) for k in range(0, 600, 3)]  # 40-100 s ago
    new = [utterance("ana", "r1", "bad", shown(k)) for k in range(900, 1000, 10)]  # the outage
    out = []
    for i, said in enumerate(old + new):
        out += a.on_utterance(said, shown(1000) + 0.1 + 0.001 * i)
    out += a.on_tick(shown(1000) + 3.0)  # held until the recovered steps are in
    taken = {s for fb in feedback(out) for s in fb.sources}
    assert taken == {u.id for u in new}
    assert a.counters["rejected.stale"] == len(old) and a.counters["rejected.rate_limited"] == 0


# -- questions ----------------------------------------------------------------------------------


def test_the_first_command_after_a_question_answers_it_credited_to_its_step():
    a = arbiter()
    asked = HelpRequest(robot="r1", episode=0, step=60, reason="stuck", detail="stuck", x=0, y=0)
    assert a.on_help(asked, shown(60)) == [] and a.counters["questions"] == 1
    praise = a.on_utterance(utterance("ana", "r1", "good", shown(61)), shown(62))
    assert feedback(praise)[0].kind == "reward"  # a qualifier is no answer to "which way?"
    out = a.on_utterance(utterance("bob", "r1", "left", shown(80)), shown(85))  # 2 s later
    (fb,) = feedback(out)
    assert (fb.kind, fb.command, credits(fb)) == ("command", "left", {60: 1.0})
    assert fb.question == asked.id  # the learner matches it by the question's id
    (answered,) = [m for m in out if isinstance(m, HelpAnswer)]
    assert (answered.question, answered.teacher, answered.meaning) == (asked.id, "bob", "left")
    assert "answer" in notices(out)[0].text
    (second,) = feedback(a.on_utterance(utterance("ana", "r1", "right", shown(86)), shown(87)))
    assert max(credits(second)) < 86 and second.question is None  # a command about then
    a.on_help(replace(asked, step=90), shown(90))
    late = a.on_utterance(utterance("ana", "r1", "left", shown(90) + 7.0), shown(99))
    assert not any(isinstance(m, HelpAnswer) for m in late)  # said 7 s after it: not an answer


def test_a_question_about_an_unknown_robot_is_refused():
    a = arbiter()
    asked = HelpRequest(robot="r9", episode=0, step=1, reason="late", detail="late", x=0, y=0)
    assert a.on_help(asked, shown(10)) == []
    assert a.counters["rejected.question_of_unknown_robot"] == 1


def test_an_answer_has_the_id_the_same_command_would_have_so_a_learner_takes_it_once():
    """An arbiter restarted without the question turns the recovered answer into a plain
    command: the same feedback id, so the learner that took the answer skips it."""
    asked = HelpRequest(robot="r1", episode=0, step=60, reason="stuck", detail="stuck", x=0, y=0)
    said = utterance("ana", "r1", "left", shown(80))
    a = arbiter()
    a.on_help(asked, shown(60))
    (answer,) = feedback(a.on_utterance(said, shown(85)))
    (command,) = feedback(arbiter().on_utterance(said, shown(85)))
    assert answer.id == command.id and credits(answer) == {60: 1.0} != credits(command)

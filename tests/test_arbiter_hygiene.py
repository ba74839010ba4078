"""The arbiter's core without the bus: duplicates, floods and rates, who may say what,
its settings, its step timeline across restarts, and the robots' questions. Times are made
up and exact."""

from __future__ import annotations

from dataclasses import replace

import pytest

from tests.arbiter_support import PERIOD, T0, VOCABULARY, arbiter, credits, feedback, notices, shown
from voxshape.cli import parser as cli_parser
from voxshape.protocol import (
    HelpAnswer,
    HelpRequest,
)
from voxshape.runtime import ConfigError
from voxshape.runtime.limits import TokenBucket
from voxshape.services.arbiter.arbiter import Arbiter
from voxshape.services.arbiter.config import (
    ArbiterConfig,
    ArbiterConfigError,
    DelayLearning,
    DelayWindow,
    parse_window,
)
from voxshape.services.arbiter.credit import StepTimeline
from voxshape.services.arbiter.hygiene import RecentIds
from voxshape.services.arbiter.node import config_from
from voxshape.services.arbiter.scripted import (
    scripted_observation,
    scripted_utterance,
)


def test_duplicates_are_dropped_and_counted():
    a = arbiter()
    said = scripted_utterance("ana", "r1", "good", shown(90))
    assert feedback(a.on_utterance(said, shown(99)))
    assert a.on_utterance(said, shown(99)) == []
    assert a.counters["rejected.duplicate"] == 1


def test_a_flood_is_cut_counted_and_the_teacher_told_once():
    a = arbiter(utterances_per_s=4.0, utterances_at_once=8.0)
    out = []
    for i in range(100):  # 100 in one second
        out += a.on_utterance(
            scripted_utterance("ana", "r1", "good", shown(90)), shown(90) + i * 0.01
        )
    # the burst, then 4/s until 0.4 s in, when each claims to have ended (said at one moment)
    assert len(feedback(out)) == 8 + 1
    limited = [n for n in notices(out) if n.kind == "rate_limited"]
    assert len(limited) == 1 and "slow down" in limited[0].text
    assert a.counters["rejected.rate_limited"] == 100 - len(feedback(out))
    other = a.on_utterance(scripted_utterance("bob", "r1", "good", shown(90)), shown(91))
    assert feedback(other)  # another teacher is not limited


def test_a_robot_time_teachers_rate_is_per_robot_second():
    """At 20x real time a simulated teacher saying one thing every robot second says 20 a
    wall second: within its rate in robot seconds. A person saying as much is a flood."""
    fast = PERIOD / 20
    config = ArbiterConfig(robot_time=frozenset({"sim"}), learning=DelayLearning(enabled=False))
    a = Arbiter(config, VOCABULARY)
    for k in range(800):
        a.on_observation(scripted_observation("r1", k, T0 + k * fast), T0 + k * fast)
    said = {"sim": 0, "ana": 0}
    for i in range(40):  # one every 10 steps: a robot second, 50 ms of wall time
        at = T0 + (400 + 10 * i) * fast
        for teacher in said:
            said[teacher] += len(
                feedback(a.on_utterance(scripted_utterance(teacher, "r1", "good", at), at))
            )
    assert said == {"sim": 40, "ana": 8 + 7}  # ana: the burst, then 4/s over 1.95 s


def test_an_unknown_robot_is_rejected_and_the_teacher_told():
    a = arbiter()
    out = a.on_utterance(scripted_utterance("ana", "r9", "good", shown(90)), shown(99))
    (notice,) = notices(out)
    assert not feedback(out) and notice.kind == "unknown_robot" and "robots: r1" in notice.text
    quiet = a.on_utterance(scripted_utterance("ana", "r1", "good", shown(99)), shown(99) + 60)
    assert notices(quiet)[0].kind == "unknown_robot"  # its simulator went quiet


def test_an_utterance_on_another_teachers_key_is_rejected():
    a = arbiter()
    assert (
        a.on_utterance(scripted_utterance("ana", "r1", "good", shown(90)), shown(99), "bob") == []
    )
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
    said = scripted_utterance("ana", "r1", "good", shown(15))  # said before the arbiter started
    assert a.on_utterance(said, shown(30)) == []  # held: r1 not seen yet
    out = []
    for k in range(30):  # recovered: they arrive late, in a burst
        a.on_observation(scripted_observation("r1", k, shown(k)), shown(30) + 0.001 * k)
    assert a.on_tick(shown(31)) == []  # still starting
    out = a.on_tick(shown(30) + 3.0)
    assert feedback(out) and notices(out)[0].kind == "understood"
    late = Arbiter(ArbiterConfig(), VOCABULARY, started_at=T0)
    assert late.on_utterance(scripted_utterance("ana", "r9", "good", T0 - 1), T0) == []
    (notice,) = notices(late.on_tick(T0 + 3.0))  # nobody came: unknown after the wait
    assert notice.kind == "unknown_robot"
    live = late.on_utterance(scripted_utterance("ana", "r8", "good", T0 + 1), T0 + 1)
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
        a.on_observation(scripted_observation("r1", k, shown(k)), shown(k))
    out = []
    for i in range(20):  # said a word every 10 steps (a second) while it was frozen
        said = scripted_utterance("ana", "r1", "good", shown(100 + 10 * i))
        out += a.on_utterance(said, shown(300) + 0.1 + 0.001 * i)
    assert len(feedback(out)) == 20 and a.counters["rejected.rate_limited"] == 0
    at_once = []
    for i in range(20):
        said = scripted_utterance("bob", "r1", "good", shown(290))
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
        a.on_observation(scripted_observation("r1", k, shown(k)), shown(1000) + 0.0001 * k)
    old = [
        scripted_utterance("ana", "r1", "good", shown(k)) for k in range(0, 600, 3)
    ]  # 40-100 s ago
    new = [
        scripted_utterance("ana", "r1", "bad", shown(k)) for k in range(900, 1000, 10)
    ]  # the outage
    out = []
    for i, said in enumerate(old + new):
        out += a.on_utterance(said, shown(1000) + 0.1 + 0.001 * i)
    out += a.on_tick(shown(1000) + 3.0)  # held until the recovered steps are in
    taken = {s for fb in feedback(out) for s in fb.sources}
    assert taken == {u.id for u in new}
    assert a.counters["rejected.stale"] == len(old) and a.counters["rejected.rate_limited"] == 0


def test_the_first_command_after_a_question_answers_it_credited_to_its_step():
    a = arbiter()
    asked = HelpRequest(robot="r1", episode=0, step=60, reason="stuck", detail="stuck", x=0, y=0)
    assert a.on_help(asked, shown(60)) == [] and a.counters["questions"] == 1
    praise = a.on_utterance(scripted_utterance("ana", "r1", "good", shown(61)), shown(62))
    assert feedback(praise)[0].kind == "reward"  # a qualifier is no answer to "which way?"
    out = a.on_utterance(scripted_utterance("bob", "r1", "left", shown(80)), shown(85))  # 2 s later
    (fb,) = feedback(out)
    assert (fb.kind, fb.command, credits(fb)) == ("command", "left", {60: 1.0})
    assert fb.question == asked.id  # the learner matches it by the question's id
    (answered,) = [m for m in out if isinstance(m, HelpAnswer)]
    assert (answered.question, answered.teacher, answered.meaning) == (asked.id, "bob", "left")
    assert "answer" in notices(out)[0].text
    (second,) = feedback(
        a.on_utterance(scripted_utterance("ana", "r1", "right", shown(86)), shown(87))
    )
    assert max(credits(second)) < 86 and second.question is None  # a command about then
    a.on_help(replace(asked, step=90), shown(90))
    late = a.on_utterance(scripted_utterance("ana", "r1", "left", shown(90) + 7.0), shown(99))
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
    said = scripted_utterance("ana", "r1", "left", shown(80))
    a = arbiter()
    a.on_help(asked, shown(60))
    (answer,) = feedback(a.on_utterance(said, shown(85)))
    (command,) = feedback(arbiter().on_utterance(said, shown(85)))
    assert answer.id == command.id and credits(answer) == {60: 1.0} != credits(command)

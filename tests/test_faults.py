"""Faults a real session meets, each on a real bus with real services, each printing its
figures as one `FAULT-FIGURES {json}` line (`benchmarks/faults.py` gathers them):

- the learner killed (-9) mid-training and restarted: it resumes from its checkpoint, and every
  credited feedback is taken exactly once;
- the router killed (-9) and restarted: everyone reconnects, nothing a teacher typed is lost;
- a service down for a while (test_faults_outages.py), hostile input (test_faults_hostile.py),
  an observer stopped (test_faults_stopped.py).

Assertions are on events and counts; durations are printed (a loose bound at most).
"""

from __future__ import annotations

import signal
import time
from collections import Counter
from dataclasses import replace

import pytest

from tests.conftest import collect, free_port, wait_present
from tests.faults_support import (
    RTF,
    STARTING_S,
    checkpoint_meta,
    figures,
    learner,
    log_entries,
    paced_sim,
    service,
    start_router,
    stop,
    typist,
)
from voxshape.protocol import (
    CreditedFeedback,
    LearningSummary,
    robot_key,
    teacher_key,
)
from voxshape.runtime import Input, Node, bus_config
from voxshape.services.arbiter.scripted import scripted_utterance


class Judging:
    """A teacher saying judgements of r1 to the arbiter, noting the learner's summaries and,
    by the phase they were published in, the credited feedback."""

    def __init__(self, node: Node, session_id: str) -> None:
        self.node = node
        self.said = node.output("utterance", teacher_key(session_id, "ana", "utterance"))
        self.published: dict[str, str] = {}
        self.phase = "before"

    def teach(self, n: int, learning: list[LearningSummary]) -> None:
        """n judgements 0.3 s apart (within the arbiter's rate limit)."""
        for k in range(n):
            self.said.put(scripted_utterance("ana", "r1", "good" if k % 2 else "bad", time.time()))
            self.listen(0.3, learning)

    def listen(self, seconds: float, learning: list[LearningSummary]) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            event = self.node.poll(0.02)
            if isinstance(event, Input):
                if isinstance(event.message, LearningSummary):
                    learning.append(event.message)
                elif isinstance(event.message, CreditedFeedback):
                    self.published[event.message.id] = self.phase


def test_a_killed_learner_resumes_from_its_checkpoint_and_loses_no_feedback(
    spawn, router, session_id, client_config, tmp_path
):
    path, every = tmp_path / "learner.npz", 1.0
    paced_sim(spawn, router, session_id)
    arbiter = service(spawn, "arbiter", router, session_id, "arbiter", cwd=tmp_path)
    first = learner(spawn, router, session_id, path, every)
    with Node("test", client_config("teacher")) as node:
        node.watch_presence()
        node.input("learning", robot_key(session_id, "r1", "learning"))
        node.input("feedback", robot_key(session_id, "r1", "feedback"))
        ana = Judging(node, session_id)
        wait_present(node, {"sim", "arbiter", "learner"})
        before: list[LearningSummary] = []
        ana.teach(8, before)  # 2.4 s of teaching: at least one checkpoint
        deadline = time.monotonic() + 60
        while not path.exists() and time.monotonic() < deadline:
            ana.teach(1, before)
        ana.teach(2, before)
        first.send_signal(signal.SIGKILL)
        killed_at = time.time()
        first.wait(10)
        saved = checkpoint_meta(path)
        saved["age_at_kill_s"] = killed_at - path.stat().st_mtime
        ana.phase = "outage"
        ana.teach(4, [])  # said while no learner runs
        second = learner(spawn, router, session_id, path, every)
        ana.phase = "restarting"
        after: list[LearningSummary] = []
        deadline = time.monotonic() + 60
        while not after and time.monotonic() < deadline:
            ana.teach(1, after)
        assert after, "the restarted learner did not learn within 60 s"
        ana.phase = "after"
        ana.teach(4, after)
        ana.listen(3, after)  # the last feedback reaches the test too
    code, counters, err = stop(second)
    assert code == 0, err
    check_resumed(err, counters, saved, checkpoint_meta(path), ana.published, before, every)
    assert stop(arbiter)[0] == 0


def check_resumed(
    err: str,
    counters: dict,
    saved: dict,
    final: dict,
    published: dict[str, str],
    before: list[LearningSummary],
    every: float,
) -> None:
    """The restarted learner resumed at the checkpoint it was killed after (its log `err`,
    its `counters`), took every credited feedback `published` once; its figures printed."""
    (started,) = log_entries(err, "learning")
    taken_at_crash, taken = set(saved["feedback_taken"]), set(final["feedback_taken"])
    applied_after_restart = counters["received.feedback"] - counters.get(
        "learner.feedback_taken_before", 0
    )
    relearned = before[-1].step - saved["step"]
    lost = set(published) - taken
    figures(
        "learner killed",
        checkpoint_every_s=every,
        steps_per_s=RTF * 10,
        checkpoint_age_at_kill_s=round(saved["age_at_kill_s"], 3),
        steps_relearned=relearned,
        steps_per_interval=RTF * 10 * every,
        feedback_published=len(published),
        feedback_published_by_phase=dict(Counter(published.values())),
        feedback_in_checkpoint_at_kill=len(taken_at_crash & set(published)),
        feedback_delivered_again_skipped=counters.get("learner.feedback_taken_before", 0),
        feedback_taken_after_restart=len(taken - taken_at_crash),
        feedback_applied_after_restart=applied_after_restart,
        feedback_lost=len(lost),
        feedback_missed_for_good=counters.get("missed.feedback", 0),
        credits_applied=counters.get("learner.feedback_credited", 0),
        credits_dropped_unknown_step=counters.get("learner.feedback_dropped.unknown_step", 0),
        credits_dropped_too_old=counters.get("learner.feedback_dropped.too_old", 0),
    )
    assert started["resumed_at_step"] == saved["step"]
    assert int(started["feedback_taken"]) == len(saved["feedback_taken"])
    # feedback before the kill, during the outage and after: how many depends on the load
    # (words before the robot's first steps are not credited), each phase must have some
    assert {"before", "outage", "after"} <= set(published.values()), published
    lost_when = [published[i] for i in lost]
    assert not lost, f"{len(lost)} of {len(published)} credited feedback never taken: {lost_when}"
    assert applied_after_restart == len(taken - taken_at_crash)  # none taken twice
    # at most one interval of learning lost (a loose bound: the loop saves on its next event)
    assert relearned <= RTF * 10 * (every + 1.0), (relearned, saved["age_at_kill_s"])


@pytest.mark.long
def test_after_a_router_restart_everyone_reconnects_and_nothing_typed_is_lost(
    spawn, session_id, tmp_path
):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = start_router(spawn, session_id, endpoint)
    paced_sim(spawn, endpoint, session_id)
    arbiter = service(spawn, "arbiter", endpoint, session_id, "arbiter", cwd=tmp_path)
    learning = learner(spawn, endpoint, session_id, tmp_path / "learner.npz", 1.0)
    config = replace(
        bus_config("test", env={}),
        session=session_id,
        node="observer",
        mode="client",
        connect=(endpoint,),
    )
    times: dict[str, float] = {}
    with Node("test", config) as node:
        node.watch_presence()
        wait_present(node, {"sim", "arbiter", "learner"})
        node.input("learning", robot_key(session_id, "r1", "learning"))
        collect(node, 1, LearningSummary, timeout=STARTING_S)  # the robot steps, and learns
        ana = typist(spawn, endpoint, session_id, tmp_path)
        wait_present(node, {"teach"})
        ana.say(4)
        collect(node, 1, LearningSummary, timeout=10)
        router.send_signal(signal.SIGKILL)
        times["killed"] = time.monotonic()
        router.wait(10)
        ana.say(5)  # typed while there is no router: 1.5 s
        while node.poll(0) is not None:  # what arrived before the kill
            pass
        times["restarted"] = time.monotonic()
        router = start_router(spawn, session_id, endpoint)
        times["listening"] = listening = time.monotonic()
        while not isinstance(event := node.poll(0.01), Input) and time.monotonic() < listening + 30:
            pass
        times["flowing"] = time.monotonic()
        assert isinstance(event, Input), "no data within 30 s of the router's restart"
        ana.say(4)
        shown = ana.shown()
    code, learnt, err = stop(learning)
    assert code == 0, err
    taken = len(checkpoint_meta(tmp_path / "learner.npz")["feedback_taken"])
    code, counters, err = stop(arbiter)
    assert code == 0, err
    check_reconnected(times, ana.typed, taken, counters, learnt, shown)


def check_reconnected(
    times: dict[str, float], typed: int, taken: int, counters: dict, learnt: dict, shown: list
) -> None:
    """Every word typed, the 5 of the outage too, understood once and taken by the learner;
    data flowing again soon after the router listens; the figures printed."""
    understood = counters.get("arbiter.notices.understood", 0)
    figures(
        "router restarted",
        router_down_s=round(times["restarted"] - times["killed"], 3),
        router_start_s=round(times["listening"] - times["restarted"], 3),
        data_again_after_listening_s=round(times["flowing"] - times["listening"], 3),
        typed=typed,
        typed_during_outage=5,
        understood_by_arbiter=understood,
        copies_dropped_by_arbiter=counters.get("arbiter.rejected.duplicate", 0),
        feedback_published=counters.get("arbiter.feedback", 0)
        + counters.get("arbiter.commands", 0),
        feedback_taken_by_learner=taken,
        notices_seen_by_teacher=sum(e["event"] == "notice" for e in shown),
        utterances_missed_for_good=counters.get("missed.utterance", 0),
        feedback_missed_for_good=learnt.get("missed.feedback", 0),
    )
    assert understood == typed, counters
    assert taken == typed  # (data flowed again within 30 s: asserted; its time is printed)

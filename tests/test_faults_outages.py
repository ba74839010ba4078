"""A service down for a while, on a real bus: the speech service killed (the teacher is
told, typed words still reach the arbiter), speech or the arbiter down and back (what was
said meanwhile is heard once). Each prints its figures as one `FAULT-FIGURES {json}` line."""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path

import pytest

from tests.conftest import collect, wait_present
from tests.faults_support import (
    OUTAGE_S,
    STARTING_S,
    Lines,
    checkpoint_meta,
    figures,
    learner,
    paced_sim,
    service,
    stop,
    teach_as_ana,
    typist,
)
from voxshape.protocol import (
    CreditedFeedback,
    LearningSummary,
    Utterance,
    robot_key,
    teacher_key,
)
from voxshape.runtime import Input, Node


def test_when_speech_dies_the_teacher_is_told_and_typed_words_still_work(
    spawn, router, session_id, client_config, tmp_path
):
    speech = service(spawn, "speech", router, session_id, "speech", "--engine", "mock")
    with Node("test", client_config("observer")) as node:
        node.watch_presence(role="speech")
        wait_present(node, {"speech"})
        node.input("utterance", teacher_key(session_id, "ana", "utterance"))
        teach = teach_as_ana(
            spawn, router, session_id, "--through-speech", "--linger", "2",
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, cwd=tmp_path,
        )  # fmt: skip
        shown = Lines(teach)
        teach.stdin.write("good\n")
        teach.stdin.flush()
        heard = collect(node, 1, Utterance, timeout=20)[0]
        speech.send_signal(signal.SIGKILL)
        killed = time.monotonic()
        told_at, told = shown.wait_for("speech", available=False)
        teach.stdin.write("bad\n")
        teach.stdin.flush()
        typed_at = time.monotonic()
        straight = collect(node, 1, Utterance, timeout=20)[0]
        arrived = time.monotonic()
        teach.stdin.close()
        assert teach.wait(30) == 1  # no robot runs: what it said taught nothing
    figures(
        "speech killed",
        teacher_told_after_s=round(told_at - killed, 3),
        typed_word_arrived_after_s=round(arrived - typed_at, 3),
    )
    assert (heard.text, heard.engine) == ("good", "mock")
    assert (
        "speech service is gone" in told["message"] and "straight to the arbiter" in told["message"]
    )
    assert (straight.text, straight.engine) == ("bad", "typed")


@pytest.mark.long
def test_audio_said_while_speech_is_down_is_recognized_when_it_is_back(
    spawn, router, session_id, client_config, tmp_path
):
    """The teacher's audio is a kept output and the speech service's input a recovering one:
    a word spoken during a 10 s outage is recognized by the restarted service."""
    clip = Path(__file__).parent / "fixtures" / "speech" / "en-voc-turn-left-kal-diphone.wav"
    speech = service(spawn, "speech", router, session_id, "speech")
    with Node("test", client_config("observer")) as node:
        node.watch_presence(role="speech")
        wait_present(node, {"speech"})
        speech.send_signal(signal.SIGKILL)
        speech.wait(10)
        killed = time.monotonic()
        node.input("utterance", teacher_key(session_id, "ana", "utterance"))
        teach = teach_as_ana(
            spawn, router, session_id, "--wav", str(clip), "--fast",
            *("--wait-speech", "0", "--linger", str(OUTAGE_S + 30)),
            stdout=subprocess.PIPE, cwd=tmp_path,
        )  # fmt: skip
        time.sleep(max(0.0, OUTAGE_S - (time.monotonic() - killed)))
        speech = service(spawn, "speech", router, session_id, "speech")
        restarted = time.monotonic()
        (heard,) = collect(node, 1, Utterance, timeout=40)
        recognized = time.monotonic()
        teach.send_signal(signal.SIGTERM)
        teach.wait(30)
    code, counters, err = stop(speech)
    assert code == 0, err
    figures(
        "speech down while a word is said",
        down_s=round(restarted - killed, 2),
        recognized_after_restart_s=round(recognized - restarted, 2),
        recovered_chunks=counters.get("received.audio", 0),
    )
    assert heard.text == "turn left" and heard.teacher == "ana"


@pytest.mark.long
def test_words_typed_while_the_arbiter_is_down_reach_the_learner_once(
    spawn, router, session_id, client_config, tmp_path
):
    """The arbiter, killed for 10 s while a teacher types, recovers the utterances and the
    robot's steps it missed and publishes their feedback; feedback ids derive from the
    utterances, so what it had published before the kill is not taken twice."""
    paced_sim(spawn, router, session_id)
    arbiter = service(spawn, "arbiter", router, session_id, "arbiter", cwd=tmp_path)
    learning = learner(spawn, router, session_id, tmp_path / "learner.npz", every=1.0)
    with Node("test", client_config("observer")) as node:
        node.watch_presence()
        wait_present(node, {"sim", "arbiter", "learner"})
        node.input("feedback", robot_key(session_id, "r1", "feedback"))
        node.input("learning", robot_key(session_id, "r1", "learning"))
        collect(node, 1, LearningSummary, timeout=STARTING_S)  # a word now has steps to credit
        ana = typist(spawn, router, session_id, tmp_path, linger=1)
        wait_present(node, {"teach"})  # on the bus (a loaded machine starts it slowly)
        ana.type("good")
        before = collect(node, 1, CreditedFeedback, timeout=20)
        arbiter.send_signal(signal.SIGKILL)
        arbiter.wait(10)
        killed = time.monotonic()
        for word in ("bad", "left", "excellent"):
            time.sleep(OUTAGE_S / 4)
            ana.type(word)
        time.sleep(max(0.0, OUTAGE_S - (time.monotonic() - killed)))
        arbiter = service(spawn, "arbiter", router, session_id, "arbiter", cwd=tmp_path)
        restarted = time.monotonic()
        seen = {before[0].id: before[0]}  # by id: feedback derived again has the same id
        copies = feedback_until(node, seen, 4, 30)
        published = time.monotonic()
        ana.shown()
    time.sleep(2)  # the learner's last feedback, then its checkpoint on stopping
    code, _, err = stop(learning)
    assert code == 0, err
    code, counters, err = stop(arbiter)
    assert code == 0, err
    taken = checkpoint_meta(tmp_path / "learner.npz")["feedback_taken"]
    times = (restarted - killed, published - restarted)
    check_typed_through(times, counters, copies, taken, seen)


def feedback_until(node: Node, seen: dict, n: int, seconds: float) -> int:
    """The credited feedback `node` hears into `seen` (by id) until it holds `n`: how many
    copies of one already seen came."""
    copies, deadline = 0, time.monotonic() + seconds
    while len(seen) < n and time.monotonic() < deadline:
        event = node.poll(0.1)
        if isinstance(event, Input) and isinstance(event.message, CreditedFeedback):
            copies += event.message.id in seen
            seen[event.message.id] = event.message
    return copies


def check_typed_through(
    times: tuple[float, float], counters: dict, copies: int, taken: list, seen: dict
) -> None:
    """The four words said reached the learner, each once; the figures printed."""
    figures(
        "arbiter down while words are typed",
        down_s=round(times[0], 2),
        feedback_after_restart_s=round(times[1], 2),
        recovered_utterances=counters.get("received.utterance", 0),
        copies_seen=copies,
        taken_by_learner=len(taken),
        refused={k: v for k, v in counters.items() if ".rejected." in k or "missed" in k},
        recovered_obs=counters.get("received.obs", 0),
    )
    said = sorted((f.kind, f.reward, f.command) for f in seen.values())
    assert said == [
        ("command", None, "left"),
        ("reward", -10.0, None),
        ("reward", 10.0, None),
        ("reward", 50.0, None),
    ]
    assert sorted(taken) == sorted(seen)  # each exactly once, the copies skipped by id

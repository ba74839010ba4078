"""Faults a real session meets, each on a real bus with real services, each printing its
figures as one `FAULT-FIGURES {json}` line (`benchmarks/faults.py` gathers them):

- the learner killed (-9) mid-training and restarted: it resumes from its checkpoint, and every
  credited feedback is taken exactly once;
- the router killed (-9) and restarted: everyone reconnects, nothing a teacher typed is lost;
- the speech service killed: the teacher is told, typed words still reach the arbiter;
- malformed messages on every topic: no service crashes, each is counted;
- a teacher flooding utterances: rate-limited, another teacher unaffected;
- an observer stopped (SIGSTOP) for 10 s, a logger, a web page or a second site's router: the
  robot keeps its pace, the words of the stop are credited then, and the logs hold everything
  (or a marked gap for per-step messages no longer kept).

Assertions are on events and counts; durations are printed (a loose bound at most).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import threading
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests import stopped_observer as so
from tests.conftest import VOXSHAPE, bus_args, collect, free_port, wait_for_port, wait_present
from tests.strategies import messages
from voxshape.launcher import router_command
from voxshape.protocol import (
    MESSAGE_TYPES,
    ROBOT_TOPICS,
    TEACHER_TOPICS,
    CreditedFeedback,
    LearningSummary,
    Observation,
    TeacherNotice,
    Utterance,
    robot_key,
    teacher_key,
    to_wire,
)
from voxshape.runtime import Input, Node, bus_config
from voxshape.services.arbiter.scripted import scripted_utterance

JSON_LOGS = {**os.environ, "VOXSHAPE_LOG_FORMAT": "json"}
RTF = 5.0  # the paced simulator's speed: 50 steps/s
# From present on the bus to stepping: a simulator loads PyBullet and its map after it joins;
# a loaded machine (a clean clone's first run beside other work) took more than 10 s.
STARTING_S = 60.0


def figures(fault: str, **values: object) -> None:
    print("FAULT-FIGURES " + json.dumps({"fault": fault, **values}), flush=True)


def service(spawn, role: str, router: str, session_id: str, node: str, *args: str, **kw):
    kw.setdefault("env", JSON_LOGS)
    return spawn([VOXSHAPE, role, *bus_args(router, session_id, node), *args], text=True, **kw)


def paced_sim(spawn, router, session_id):
    return service(spawn, "sim", router, session_id, "sim", "--rtf", str(RTF), "--seed", "0")


def stop(proc: subprocess.Popen, timeout: float = 30.0) -> tuple[int, dict, str]:
    """SIGTERM, then its exit code, its last counters and its stderr."""
    proc.send_signal(signal.SIGTERM)
    return finish(proc, timeout)


def finish(proc: subprocess.Popen, timeout: float = 30.0) -> tuple[int, dict, str]:
    """Its exit code, its last counters and its stderr, once it has ended."""
    _, err = proc.communicate(timeout=timeout)
    return proc.returncode, last_counters(err), err


def last_counters(stderr: str) -> dict:
    found: dict = {}
    for line in stderr.splitlines():
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:
            continue
        if entry.get("message") == "counters":
            found = {k: v for k, v in entry.items() if k not in ("time", "level", "logger")}
    return found


def log_entries(stderr: str, message: str) -> list[dict]:
    out = []
    for line in stderr.splitlines():
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:
            continue
        if entry.get("message") == message:
            out.append(entry)
    return out


def checkpoint_meta(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as data:
        return json.loads(str(data["meta"]))


# -- the learner killed mid-training ----------------------------------------------------------
def learner(spawn, router, session_id, path: Path, every: float):
    return service(
        spawn,
        "learner",
        router,
        session_id,
        "learner",
        *("--checkpoint", str(path), "--checkpoint-every", str(every), "--seed", "0"),
    )


def test_a_killed_learner_resumes_from_its_checkpoint_and_loses_no_feedback(
    spawn, router, session_id, client_config, tmp_path
):
    path, every = tmp_path / "learner.npz", 1.0
    paced_sim(spawn, router, session_id)
    arbiter = service(spawn, "arbiter", router, session_id, "arbiter", cwd=tmp_path)
    first = learner(spawn, router, session_id, path, every)
    published: dict[str, str] = {}
    phase = "before"
    with Node("test", client_config("teacher")) as node:
        node.watch_presence()
        node.input("learning", robot_key(session_id, "r1", "learning"))
        node.input("feedback", robot_key(session_id, "r1", "feedback"))
        said = node.output("utterance", teacher_key(session_id, "ana", "utterance"))
        wait_present(node, {"sim", "arbiter", "learner"})

        def teach(n: int, learning: list[LearningSummary]) -> None:
            """n judgements 0.3 s apart (within the arbiter's rate limit), meanwhile noting
            the learner's summaries and the feedback the arbiter published."""
            for k in range(n):
                said.put(scripted_utterance("ana", "r1", "good" if k % 2 else "bad", time.time()))
                deadline = time.monotonic() + 0.3
                while time.monotonic() < deadline:
                    event = node.poll(0.02)
                    if isinstance(event, Input):
                        if isinstance(event.message, LearningSummary):
                            learning.append(event.message)
                        elif isinstance(event.message, CreditedFeedback):
                            published[event.message.id] = phase

        before: list[LearningSummary] = []
        teach(8, before)  # 2.4 s of teaching: at least one checkpoint
        while not path.exists():
            teach(1, before)
        teach(2, before)
        first.send_signal(signal.SIGKILL)
        killed_at = time.time()
        first.wait(10)
        saved = checkpoint_meta(path)
        saved_age = killed_at - path.stat().st_mtime
        phase = "outage"
        outage: list[LearningSummary] = []
        teach(4, outage)  # said while no learner runs
        second = learner(spawn, router, session_id, path, every)
        phase = "restarting"
        after: list[LearningSummary] = []
        deadline = time.monotonic() + 60
        while not after and time.monotonic() < deadline:
            teach(1, after)
        assert after, "the restarted learner did not learn within 60 s"
        phase = "after"
        teach(4, after)
        deadline = time.monotonic() + 3  # the last feedback reaches the test too
        while time.monotonic() < deadline:
            event = node.poll(0.05)
            if isinstance(event, Input) and isinstance(event.message, CreditedFeedback):
                published[event.message.id] = phase
    code, counters, err = stop(second)
    assert code == 0, err
    (started,) = log_entries(err, "learning")
    final = checkpoint_meta(path)
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
        checkpoint_age_at_kill_s=round(saved_age, 3),
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
    assert relearned <= RTF * 10 * (every + 1.0), (relearned, saved_age)
    assert stop(arbiter)[0] == 0


# -- the router killed and restarted -----------------------------------------------------------
def start_router(spawn, session_id: str, endpoint: str) -> subprocess.Popen:
    proc = spawn(
        router_command("--session", session_id, "--node", "router", "--listen", endpoint),
        text=True,
        env=JSON_LOGS,
    )
    wait_for_port(int(endpoint.rsplit(":", 1)[1]))
    return proc


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
    with Node("test", config) as node:
        node.watch_presence()
        wait_present(node, {"sim", "arbiter", "learner"})
        node.input("learning", robot_key(session_id, "r1", "learning"))
        collect(node, 1, LearningSummary, timeout=STARTING_S)  # the robot steps, and learns
        teach = service(
            spawn,
            "teach",
            endpoint,
            session_id,
            "teach",
            *("--teacher", "ana", "--robot", "r1", "--json", "--linger", "4"),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            cwd=tmp_path,
        )
        wait_present(node, {"teach"})
        typed = 0

        def say(n: int) -> None:
            nonlocal typed
            for _ in range(n):
                teach.stdin.write("good\n" if typed % 2 else "bad\n")
                teach.stdin.flush()
                typed += 1
                time.sleep(0.3)

        say(4)
        collect(node, 1, LearningSummary, timeout=10)
        router.send_signal(signal.SIGKILL)
        killed = time.monotonic()
        router.wait(10)
        say(5)  # typed while there is no router: 1.5 s
        while node.poll(0) is not None:  # what arrived before the kill
            pass
        restarted = time.monotonic()
        router = start_router(spawn, session_id, endpoint)
        listening = time.monotonic()
        while not isinstance(event := node.poll(0.01), Input) and time.monotonic() < listening + 30:
            pass
        flowing = time.monotonic()
        assert isinstance(event, Input), "no data within 30 s of the router's restart"
        say(4)
        teach.stdin.close()
        teach.wait(30)
        shown = [json.loads(line) for line in teach.stdout.read().splitlines()]
    code, learnt, err = stop(learning)
    assert code == 0, err
    taken = len(checkpoint_meta(tmp_path / "learner.npz")["feedback_taken"])
    code, counters, err = stop(arbiter)
    assert code == 0, err
    understood = counters.get("arbiter.notices.understood", 0)
    notices = [e for e in shown if e["event"] == "notice"]
    figures(
        "router restarted",
        router_down_s=round(restarted - killed, 3),
        router_start_s=round(listening - restarted, 3),
        data_again_after_listening_s=round(flowing - listening, 3),
        typed=typed,
        typed_during_outage=5,
        understood_by_arbiter=understood,
        copies_dropped_by_arbiter=counters.get("arbiter.rejected.duplicate", 0),
        feedback_published=counters.get("arbiter.feedback", 0)
        + counters.get("arbiter.commands", 0),
        feedback_taken_by_learner=taken,
        notices_seen_by_teacher=len(notices),
        utterances_missed_for_good=counters.get("missed.utterance", 0),
        feedback_missed_for_good=learnt.get("missed.feedback", 0),
    )
    assert understood == typed, counters
    assert taken == typed
    assert flowing - listening < 5.0  # target 1 s: printed above, a loose bound here


# -- the speech service killed ---------------------------------------------------------------
class Lines:
    """A child's JSON stdout lines as they come, with their arrival time (a thread reads)."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.got: list[tuple[float, dict]] = []
        self._thread = threading.Thread(target=self._read, args=(proc,), daemon=True)
        self._thread.start()

    def _read(self, proc: subprocess.Popen) -> None:
        for line in proc.stdout:
            with contextlib.suppress(json.JSONDecodeError):
                self.got.append((time.monotonic(), json.loads(line)))

    def wait_for(self, event: str, timeout: float = 15.0, **match: object) -> tuple[float, dict]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for at, entry in list(self.got):
                if entry.get("event") == event and all(entry.get(k) == v for k, v in match.items()):
                    return at, entry
            time.sleep(0.02)
        raise AssertionError(f"no {event} {match} within {timeout} s: {self.got}")


def test_when_speech_dies_the_teacher_is_told_and_typed_words_still_work(
    spawn, router, session_id, client_config, tmp_path
):
    speech = service(spawn, "speech", router, session_id, "speech", "--engine", "mock")
    with Node("test", client_config("observer")) as node:
        node.watch_presence(role="speech")
        wait_present(node, {"speech"})
        node.input("utterance", teacher_key(session_id, "ana", "utterance"))
        teach = service(
            spawn,
            "teach",
            router,
            session_id,
            "teach",
            *("--teacher", "ana", "--robot", "r1", "--json", "--through-speech", "--linger", "2"),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            cwd=tmp_path,
        )
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


OUTAGE_S = 10.0  # how long a service stays down in the outage tests


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
        teach = service(
            spawn,
            "teach",
            router,
            session_id,
            "teach",
            *("--teacher", "ana", "--robot", "r1", "--json", "--wav", str(clip), "--fast"),
            *("--wait-speech", "0", "--linger", str(OUTAGE_S + 30)),
            stdout=subprocess.PIPE,
            cwd=tmp_path,
        )
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
        teach = service(
            spawn,
            "teach",
            router,
            session_id,
            "teach",
            *("--teacher", "ana", "--robot", "r1", "--json", "--linger", "1"),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            cwd=tmp_path,
        )
        wait_present(node, {"teach"})  # on the bus (a loaded machine starts it slowly)
        teach.stdin.write("good\n")
        teach.stdin.flush()
        before = collect(node, 1, CreditedFeedback, timeout=20)
        arbiter.send_signal(signal.SIGKILL)
        arbiter.wait(10)
        killed = time.monotonic()
        for word in ("bad", "left", "excellent"):
            time.sleep(OUTAGE_S / 4)
            teach.stdin.write(f"{word}\n")
            teach.stdin.flush()
        time.sleep(max(0.0, OUTAGE_S - (time.monotonic() - killed)))
        arbiter = service(spawn, "arbiter", router, session_id, "arbiter", cwd=tmp_path)
        restarted = time.monotonic()
        seen = {before[0].id: before[0]}  # by id: feedback derived again has the same id
        copies, deadline = 0, time.monotonic() + 30
        while len(seen) < 4 and time.monotonic() < deadline:
            event = node.poll(0.1)
            if isinstance(event, Input) and isinstance(event.message, CreditedFeedback):
                copies += event.message.id in seen
                seen[event.message.id] = event.message
        published = time.monotonic()
        teach.stdin.close()
        teach.wait(60)
    time.sleep(2)  # the learner's last feedback, then its checkpoint on stopping
    code, _, err = stop(learning)
    assert code == 0, err
    code, counters, err = stop(arbiter)
    assert code == 0, err
    taken = checkpoint_meta(tmp_path / "learner.npz")["feedback_taken"]
    figures(
        "arbiter down while words are typed",
        down_s=round(restarted - killed, 2),
        feedback_after_restart_s=round(published - restarted, 2),
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


# -- a teacher flooding -------------------------------------------------------------------------
def test_a_flooding_teacher_is_rate_limited_and_another_is_unaffected(
    spawn, router, session_id, client_config, tmp_path
):
    paced_sim(spawn, router, session_id)
    arbiter = service(spawn, "arbiter", router, session_id, "arbiter", cwd=tmp_path)
    flood_n, ana_n = 480, 8  # the flood: 200 per second while ana speaks
    with Node("test", client_config("teachers")) as node:
        node.watch_presence()
        wait_present(node, {"sim", "arbiter"})
        node.input("obs", robot_key(session_id, "r1", "obs"))
        collect(node, 1, Observation)
        time.sleep(1.0)  # the arbiter has a second of the robot's steps: none is too late
        for teacher in ("ana", "flood"):
            node.input("notice", teacher_key(session_id, teacher, "notice"))
        ana = node.output("utterance", teacher_key(session_id, "ana", "utterance"))
        flood = node.output("utterance", teacher_key(session_id, "flood", "utterance"))
        started = time.monotonic()

        def flooding() -> None:
            for _ in range(flood_n):
                flood.put(scripted_utterance("flood", "r1", "good", time.time()))
                time.sleep(0.005)

        notices: list[tuple[float, TeacherNotice]] = []

        def listen(seconds: float) -> None:
            deadline = time.monotonic() + seconds
            while time.monotonic() < deadline:
                event = node.poll(0.01)
                if isinstance(event, Input) and isinstance(event.message, TeacherNotice):
                    notices.append((time.monotonic(), event.message))

        thread = threading.Thread(target=flooding)
        thread.start()
        sent: dict[str, float] = {}
        for _ in range(ana_n):
            said = scripted_utterance("ana", "r1", "good", time.time())
            sent[said.id] = time.monotonic()
            ana.put(said)
            listen(0.3)
        thread.join(30)
        flood_s = time.monotonic() - started
        listen(2)
    code, counters, err = stop(arbiter)
    assert code == 0, err
    ana_latency = sorted(at - sent[n.utterance] for at, n in notices if n.utterance in sent)
    kinds = [(n.teacher, n.kind) for _, n in notices]
    flood_understood = kinds.count(("flood", "understood"))
    figures(
        "teacher flooding",
        flood_sent=flood_n,
        flood_understood=flood_understood,
        flood_rate_limited=counters.get("arbiter.rejected.rate_limited", 0),
        flood_notices_rate_limited=kinds.count(("flood", "rate_limited")),
        ana_sent=ana_n,
        ana_understood=kinds.count(("ana", "understood")),
        ana_notice_latency_p50_ms=round(1000 * ana_latency[len(ana_latency) // 2], 2),
        ana_notice_latency_max_ms=round(1000 * ana_latency[-1], 2),
        seconds=round(flood_s, 2),
    )
    assert kinds.count(("ana", "understood")) == ana_n
    assert flood_understood + counters["arbiter.rejected.rate_limited"] == flood_n
    assert flood_understood <= 8 + 4 * flood_s + 1  # burst 8, 4 per second
    assert kinds.count(("flood", "rate_limited")) <= flood_s + 2  # one notice a second


# -- malformed messages on every topic -----------------------------------------------------------
TOPICS = {**{("robot", t): c for t, c in ROBOT_TOPICS.items()}}
TOPICS |= {("teacher", t): c for t, c in TEACHER_TOPICS.items()}
OWNER = {"robot": "r1", "teacher": "ana"}


@st.composite
def malformed(draw: st.DrawFn) -> tuple[tuple[str, str], bytes]:
    """A topic and a payload that its subscribers must reject: garbage, a message of another
    type, or a message of the topic's type with a field broken, missing or unknown."""
    topic = draw(st.sampled_from(sorted(TOPICS)))
    kind = draw(st.sampled_from(["garbage", "other_type", "broken", "missing", "unknown"]))
    if kind == "garbage":  # 0xc1 is never valid msgpack
        return topic, b"\xc1" + draw(st.binary(max_size=200))
    cls = TOPICS[topic]
    if kind == "other_type":
        other = draw(st.sampled_from(sorted(set(MESSAGE_TYPES.values()) - {cls}, key=str)))
        return topic, msgpack.packb(to_wire(draw(messages(other))))
    wire = to_wire(draw(messages(cls)))
    name = draw(st.sampled_from(sorted(set(wire) - {"schema", "type"})))
    if kind == "broken":
        wire[name] = {"not": [name]}
    elif kind == "missing":
        del wire[name]
    else:
        wire["not_a_field"] = wire[name]
    return topic, msgpack.packb(wire)


def gather_malformed(n: int) -> list[tuple[tuple[str, str], bytes]]:
    cases: list = []

    @settings(
        max_examples=n,
        derandomize=True,
        database=None,
        deadline=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(malformed())
    def gather(case: tuple[tuple[str, str], bytes]) -> None:
        cases.append(case)

    gather()
    return cases


# What each service subscribes to, as (scope, topic) -> its input's name.
SUBSCRIBED = {
    "sim": {("robot", "action"): "action"},
    "learner": {("robot", "obs"): "obs", ("robot", "feedback"): "feedback"},
    "arbiter": {
        ("robot", "obs"): "obs",
        ("teacher", "utterance"): "utterance",
        ("teacher", "clock"): "clock",
    },
    "speech-mock": {("teacher", "said"): "said"},
    "speech": {("teacher", "audio"): "audio"},
}


@pytest.mark.long
def test_malformed_messages_on_every_topic_crash_nothing_and_each_is_counted(
    spawn, router, session_id, client_config, tmp_path
):
    cases = gather_malformed(300)
    services = {
        "sim": paced_sim(spawn, router, session_id),
        "learner": learner(spawn, router, session_id, tmp_path / "learner.npz", 1.0),
        "arbiter": service(spawn, "arbiter", router, session_id, "arbiter", cwd=tmp_path),
        "speech-mock": service(
            spawn, "speech", router, session_id, "speech-mock", "--engine", "mock"
        ),
        "speech": service(spawn, "speech", router, session_id, "speech"),
        "logger": service(
            spawn,
            "logger",
            router,
            session_id,
            "logger",
            *("--no-recording", "--serve-port", "0"),
            cwd=tmp_path,
        ),
    }
    services["teach"] = service(
        spawn,
        "teach",
        router,
        session_id,
        "teach",
        *("--teacher", "ana", "--robot", "r1", "--json"),
        stdin=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        cwd=tmp_path,
    )
    with Node("test", client_config("fuzzer")) as node:
        node.watch_presence()
        wait_present(node, set(services))
        outputs = {
            (scope, topic): node.zenoh.declare_publisher(
                (robot_key if scope == "robot" else teacher_key)(session_id, OWNER[scope], topic),
                congestion_control=zenoh.CongestionControl.BLOCK,
            )
            for scope, topic in TOPICS
        }
        started = time.monotonic()
        for topic, payload in cases:
            outputs[topic].put(payload)
        sent_s = time.monotonic() - started
        time.sleep(2.0)  # all of it reaches everyone
        alive = {name: proc.poll() is None for name, proc in services.items()}
        for publisher in outputs.values():
            publisher.undeclare()
    teach = services.pop("teach")
    teach.stdin.close()  # it ends when its input does
    for proc in services.values():
        proc.send_signal(signal.SIGTERM)
    sent = {topic: sum(t == topic for t, _ in cases) for topic in TOPICS}
    counted, exits = {}, {"teach": teach.wait(30)}
    for name, proc in services.items():
        exits[name], counters, _ = finish(proc)
        counted[name] = sum(
            counters.get(f"rejected.{i}", 0) for i in SUBSCRIBED.get(name, {}).values()
        )
    expected = {name: sum(sent[t] for t in topics) for name, topics in SUBSCRIBED.items()}
    figures(
        "malformed messages",
        cases=len(cases),
        sent_per_topic={f"{s}/{t}": n for (s, t), n in sent.items()},
        sent_in_s=round(sent_s, 3),
        services_alive=sum(alive.values()),
        services=len(alive),
        rejected_counted=counted,
        rejected_expected=expected,
    )
    assert all(alive.values()), alive
    assert all(code == 0 for code in exits.values()), exits
    assert {name: counted[name] for name in expected} == expected


# -- stopped observers ------------------------------------------------------------------------
def check_stopped_observer(name: str, seen: so.Seen, logs: dict[str, Path]) -> None:
    """The robot kept its pace, the words said during the stop were credited then (the
    commands carried out in order), and each log has every word and feedback, and every
    observation or a gap marked for it."""
    pace = {k: [round(v) for v in seen.windows(k)] for k in seen.phases}
    commands = [w for _, w in so.DURING if w in ("left", "right")]
    during = seen.during_stop([*commands, ""])
    held = {site: so.logged(path) for site, path in logs.items()}
    figures(
        f"{name} stopped {so.STOP_S:g} s",
        steps_per_s=pace,
        slowest_window_of_the_stop=min(pace["stopped"]),
        robot_stood_without_an_action=seen.stood,
        pace_before=round(seen.before()),
        feedback_during_stop=len(during),
        teacher_actions=so.in_order(seen.teacher_actions),
        logged={
            site: {
                "utterances": f"{len(set(seen.utterances) & h.utterances)}/{len(seen.utterances)}",
                "feedback": f"{len(set(seen.feedback) & h.feedback)}/{len(seen.feedback)}",
                "obs": len(h.obs_steps),
                "missed_marked": dict(h.missed),
                "obs_unaccounted": h.obs_unaccounted,
            }
            for site, h in held.items()
        },
    )
    assert min(pace["stopped"]) > seen.before() / 4, pace
    assert len(during) == len(so.DURING), f"credited during the stop: {during}"
    assert so.in_order(seen.teacher_actions)[-len(commands) :] == commands
    for site, h in held.items():
        assert set(seen.utterances) <= h.utterances, site
        assert set(seen.feedback) <= h.feedback, site
        assert not {k: n for k, n in h.missed.items() if k not in ("obs", "action", "learning")}
        assert h.obs_unaccounted == 0, (site, h.missed)


def events_of(run: Path, session_id: str) -> Path:
    return run / "runs" / session_id / "events.msgpack"


def stopped_observer_run(spawn, router, session_id, client_config, run: Path, observer=None):
    """The session of tests/stopped_observer.py with `observer(session)` stopped (default:
    its logger), then ended: what the test's node saw."""
    procs = so.start_session(spawn, router, session_id, run)
    seen = so.Seen()
    with Node("test", client_config("watch")) as node:
        node.watch_presence()
        wait_present(node, {"sim", "learner", "arbiter", "logger", "teach"})
        so.watch(node, session_id)
        stopped = procs["logger"] if observer is None else observer()
        so.stop_for(node, seen, stopped, procs["teach"])
        procs["teach"].stdin.close()
        procs["teach"].wait(30)
        for name in ("sim", "learner", "arbiter", "logger"):
            procs[name].send_signal(signal.SIGTERM)
            assert procs[name].wait(30) == 0, name
    seen.stood = last_counters((run / "sim.log").read_text()).get("stopped_without_action", 0)
    return seen


@pytest.mark.long
def test_a_stopped_logger_never_slows_the_robot_and_logs_everything_after(
    spawn, router, session_id, client_config, tmp_path
):
    """The logger stopped (SIGSTOP) for 10 s: no 0.5 s window of the robot's pace below a
    quarter of its pace before; the words of the stop credited during it; when the logger
    runs again it gets back what it missed, and marks a gap for what is no longer kept."""
    seen = stopped_observer_run(spawn, router, session_id, client_config, tmp_path)
    check_stopped_observer(
        "logger", seen, {"main": tmp_path / "runs" / session_id / "events.msgpack"}
    )


@pytest.mark.long
def test_a_stopped_web_page_never_slows_the_robot(
    spawn, router, session_id, client_config, tmp_path
):
    def web():
        return so.service(spawn, "web", router, session_id, "web", "--port", str(free_port()),
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip

    seen = stopped_observer_run(spawn, router, session_id, client_config, tmp_path, web)
    check_stopped_observer(
        "web page", seen, {"main": tmp_path / "runs" / session_id / "events.msgpack"}
    )


@pytest.mark.long
def test_a_stopped_second_site_router_never_slows_the_robot(
    spawn, router, session_id, client_config, tmp_path
):
    """A second site's router (meshed with the session's) and its own logger: the router
    stopped, the robot keeps its pace and both logs have everything, gaps marked."""
    site2 = tmp_path / "site2"
    site2.mkdir()

    def second_site():
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        argv = router_command(
            "--session", session_id, "--node", "router2", "--listen", endpoint, "--connect", router
        )
        other = spawn(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wait_for_port(int(endpoint.rsplit(":", 1)[1]))
        so.service(spawn, "logger", endpoint, session_id, "logger2", "--serve-port", "0",
                   cwd=site2, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
        time.sleep(3.0)  # the sites meshed, the logger subscribed through both
        return other

    seen = stopped_observer_run(spawn, router, session_id, client_config, tmp_path, second_site)
    time.sleep(3.0)  # the second site's logger catches up before it is stopped
    logs = {"main": events_of(tmp_path, session_id), "site2": events_of(site2, session_id)}
    check_stopped_observer("second site's router", seen, logs)

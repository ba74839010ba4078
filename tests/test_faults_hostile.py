"""Hostile input on a real bus: a teacher flooding utterances is rate-limited and another is
unaffected; malformed messages on every topic crash no service and each is counted."""

from __future__ import annotations

import signal
import subprocess
import threading
import time
from pathlib import Path

import msgpack
import pytest
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.conftest import collect, wait_present
from tests.faults_support import (
    figures,
    finish,
    learner,
    paced_sim,
    service,
    stop,
    teach_as_ana,
)
from tests.strategies import messages
from voxshape.protocol import (
    MESSAGE_TYPES,
    ROBOT_TOPICS,
    TEACHER_TOPICS,
    Observation,
    TeacherNotice,
    robot_key,
    teacher_key,
    to_wire,
)
from voxshape.runtime import Input, Node
from voxshape.services.arbiter.scripted import scripted_utterance


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
    check_flood(notices, sent, counters, flood_n, ana_n, flood_s)


def check_flood(
    notices: list[tuple[float, TeacherNotice]],
    sent: dict[str, float],
    counters: dict,
    flood_n: int,
    ana_n: int,
    flood_s: float,
) -> None:
    """Every word of ana's understood; the flood's cut to the rate limit, each word of it
    counted once, and told once a second; the figures printed."""
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
TOPICS = {("robot", t): c for t, c in ROBOT_TOPICS.items()} | {
    ("teacher", t): c for t, c in TEACHER_TOPICS.items()
}
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


def fuzzed_services(spawn, router: str, session_id: str, tmp_path: Path) -> dict:
    """Every service that subscribes to something, by its node name, each started."""
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
    services["teach"] = teach_as_ana(
        spawn, router, session_id, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, cwd=tmp_path
    )
    return services


@pytest.mark.long
def test_malformed_messages_on_every_topic_crash_nothing_and_each_is_counted(
    spawn, router, session_id, client_config, tmp_path
):
    cases = gather_malformed(300)
    services = fuzzed_services(spawn, router, session_id, tmp_path)
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

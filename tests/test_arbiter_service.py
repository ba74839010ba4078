"""`voxshape arbiter` on a real bus (a router process, loopback): utterances in, credited
feedback, notices and statistics out, teacher clocks synced, bad input survived."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import msgpack
import pytest

from tests.conftest import ROOT, VOXSHAPE, bus_args, collect, wait_present
from voxshape.protocol import (
    CreditedFeedback,
    TeacherNotice,
    TeachingStats,
    robot_key,
    teacher_key,
    to_wire,
)
from voxshape.runtime import Node, Output
from voxshape.runtime.clock import ClockSyncError, sync_clock
from voxshape.services.arbiter.scripted import scripted_observation, scripted_utterance

PERIOD = 0.05  # the fake simulator's step period
SKEW = 5.0  # the teacher's clock is this far ahead


def test_an_utterance_becomes_credited_feedback_for_the_steps_the_teacher_saw(
    spawn, router, session_id, client_config, tmp_path
):
    arbiter = spawn(
        [VOXSHAPE, "arbiter", *bus_args(router, session_id, "arbiter")], cwd=tmp_path, text=True
    )
    with Node("test", client_config("teacher")) as node:
        node.watch_presence(node="arbiter")
        node.input("feedback", robot_key(session_id, "r1", "feedback"))
        node.input("notice", teacher_key(session_id, "ana", "notice"))
        node.input("teaching", robot_key(session_id, "r1", "teaching"))
        obs = node.output("obs", robot_key(session_id, "r1", "obs"))
        said = node.output("utterance", teacher_key(session_id, "ana", "utterance"))
        wait_present(node, "arbiter")

        teacher_clock = lambda: time.time() + SKEW  # noqa: E731
        estimate = sync_clock(node, "ana", clock=teacher_clock)
        # within what the round trip allows (NTP's bound; the round trip itself is load's)
        assert abs(estimate.offset + SKEW) <= estimate.rtt / 2 + 0.002, estimate

        start = time.time()  # a simulator stepping every PERIOD: step k shown at start + k P
        for k in range(30):
            time.sleep(max(0.0, start + k * PERIOD - time.time()))
            obs.put(scripted_observation("r1", k, start + k * PERIOD))
        # Seen at the middle of step 20, said 0.5 s later on the teacher's clock: TAMER's
        # 0.2-0.8 s window covers steps 14.5 to 26.5.
        onset = start + 20.5 * PERIOD + 0.5 + SKEW
        said.put(scripted_utterance("ana", "r1", "good", onset))
        # The feedback and the teacher's notice travel on different keys, in either order.
        got = collect(node, 2, (CreditedFeedback, TeacherNotice))
        (fb,) = [m for m in got if isinstance(m, CreditedFeedback)]
        (notice,) = [m for m in got if isinstance(m, TeacherNotice)]
        weights = {c.step: c.weight for c in fb.credits}
        assert sorted(weights) == list(range(14, 27)), weights
        expected = {k: 1 / 24 if k in (14, 26) else 1 / 12 for k in range(14, 27)}
        assert all(abs(weights[k] - w) < 0.01 for k, w in expected.items()), weights
        assert (fb.kind, fb.reward, fb.teachers) == ("reward", 10.0, ("ana",))
        assert notice.kind == "understood" and notice.meaning == "good"

        refused_then_understood(node, session_id, said, onset)
        (command,) = collect(node, 1, CreditedFeedback)
        assert (command.kind, command.command) == ("command", "forward")
        # credited as "good" is, to the 0.6 s the teacher saw (on the arbiter's estimate of
        # the simulator's clock: load moves it a few steps), not to the last step alone
        steps = sorted(c.step for c in command.credits)
        assert steps == list(range(steps[0], steps[-1] + 1)) and len(steps) >= 10, steps
        assert 10 <= steps[0] <= 20 and steps[-1] <= 29, steps

        stats = collect(node, 1, TeachingStats, timeout=5)[0]
        (ana,) = stats.teachers
        assert ana.clock_offset == pytest.approx(-SKEW, abs=0.005)
        assert ana.utterances >= 1 and ana.understood >= 1

    arbiter.send_signal(signal.SIGTERM)
    _, err = arbiter.communicate(timeout=20)
    assert arbiter.returncode == 0, err
    assert "rejected.utterance=2" in err, err
    assert (
        "arbiter.rejected.not_understood=1" in err and "arbiter.clock_reports=8" in err
    )  # n=8: every probe after the first


def refused_then_understood(node: Node, session_id: str, said: Output, onset: float) -> None:
    """Malformed utterances are rejected without harm; unknown words get a notice; then a
    command is said."""
    key = teacher_key(session_id, "ana", "utterance")
    bad = to_wire(scripted_utterance("ana", "r1", "good", onset))
    node.zenoh.put(key, msgpack.packb({**bad, "confidence": 2.0}))
    node.zenoh.put(key, b"\x00garbage")
    said.put(scripted_utterance("ana", "r1", "cucumber", onset + 0.1))
    notice = collect(node, 1, TeacherNotice)[0]
    assert notice.kind == "not_understood" and "not in the vocabulary" in notice.text
    said.put(scripted_utterance("ana", "r1", "avanza", onset + 0.2))


def test_bad_settings_are_a_clear_error():
    result = subprocess.run(
        [VOXSHAPE, "arbiter", "--delay", "1:0.5"], capture_output=True, text=True, timeout=30
    )
    assert result.returncode == 2
    assert "delay window 1:0.5 needs 0 <= lo < hi (seconds), e.g. 0.2:0.8" in result.stderr
    assert "Traceback" not in result.stderr


def test_the_benchmark_prints_latency_and_accuracy(tmp_path):
    script = ROOT / "benchmarks" / "arbiter.py"
    argv = [sys.executable, str(script), "--json", "--utterances", "40", "--seeds", "1"]
    argv += ["--steps", "1500", "--delays", "0,1.7", "--skews=-5,5", "--jitters", "0"]
    result = subprocess.run(argv, capture_output=True, text=True, timeout=90, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    figures = json.loads(result.stdout)
    latency = figures["latency"]
    assert latency["lost"] == 0 and latency["latency_n"] == 40
    assert 0 < latency["latency_p50_ms"] <= latency["latency_p99_ms"]
    assert "max" in latency["summary"] and "(n=40)" in latency["summary"]  # 40: no p99
    credit = {(r["delay_s"], r["skew_s"]): r for r in figures["credit"]}
    assert len(credit) == 4 and credit[1.7, 5.0]["learnt_within_one_step"] == 1.0
    assert credit[1.7, 5.0]["tamer_within_one_step"] == 0.0  # its fixed window misses it
    print(latency)


def test_sync_clock_says_when_no_arbiter_answers(client_config):
    with (
        Node("test", client_config("lonely")) as node,
        pytest.raises(ClockSyncError, match="is `voxshape arbiter` running"),
    ):
        sync_clock(node, "ana", n=2, reply_wait=0.1)

"""`voxshape bench arbiter`: the arbiter's figures.

- latency: from an Utterance published to its CreditedFeedback received, over zenoh on
  loopback, through a router process and a `voxshape arbiter` process started here (and ended
  by pid), while observations stream in (no speech recognition involved);
- credit accuracy (pure, in process): the share of a scripted teacher's judgements credited
  within one step of the step they reacted to, once their delay is learnt, for reaction
  delays 0-2 s and clock skews of +-5 s.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
import uuid
from dataclasses import replace
from pathlib import Path

from protocol import CreditedFeedback, robot_key, teacher_key
from services.arbiter.scripted import ScriptedTeacher, observation, rehearse, utterance
from services.runtime import Input, Node, Output, Presence, bus_config, free_loopback_port

ROBOT, TEACHER = "r1", "bench"
OBS_EVERY = 0.1  # seconds between observations: a person-paced session (10 Hz)
REPLY_TIMEOUT = 2.0


def percentile(values: list[float], q: float) -> float:
    """Nearest-rank percentile (q in 0-100) of a non-empty list."""
    ordered = sorted(values)
    rank = max(1, min(len(ordered), round(q / 100 * len(ordered) + 0.5)))
    return ordered[rank - 1]


def measure_latency(utterances: int = 1000, warmup_s: float = 1.2) -> dict:
    """Latency figures in milliseconds, and how many feedbacks never came."""
    session = f"bench{uuid.uuid4().hex[:8]}"
    router = f"tcp/127.0.0.1:{free_loopback_port()}"
    voxshape = str(Path(sys.executable).parent / "voxshape")
    common = ["--session", session, "--connect", router]
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    unlimited = ["--set", "utterances_per_s=1e6", "--set", "utterances_at_once=1e6"]
    children = [
        subprocess.Popen([voxshape, "router", "--session", session, "--listen", router], **quiet)
    ]
    try:
        children.append(subprocess.Popen([voxshape, "arbiter", *common, *unlimited], **quiet))
        config = replace(bus_config("bench"), session=session, connect=(router,))
        with Node("bench", config, quiet=True) as node:
            node.input("feedback", robot_key(session, ROBOT, "feedback"))
            node.watch_presence(role="arbiter")
            obs = node.output("obs", robot_key(session, ROBOT, "obs"))
            said = node.output("utterance", teacher_key(session, TEACHER, "utterance"))
            stream = _ObservationStream(obs)
            _wait_for_arbiter(node, stream, said)
            deadline = time.monotonic() + warmup_s
            while time.monotonic() < deadline:  # a history of steps to credit
                stream.maybe_step()
                time.sleep(OBS_EVERY / 2)
            latencies, lost = [], 0
            for _ in range(utterances):
                stream.maybe_step()
                u = utterance(TEACHER, ROBOT, "good", onset=time.time() - 0.3, confidence=1.0)
                t0 = time.perf_counter()
                said.put(u)
                if _wait_for_feedback(node, u.id):
                    latencies.append((time.perf_counter() - t0) * 1000)
                else:
                    lost += 1
    finally:
        _stop(children)
    if not latencies:
        raise RuntimeError("no credited feedback came back from the arbiter")
    return {
        "utterances": utterances,
        "lost": lost,
        "latency_p50_ms": round(percentile(latencies, 50), 3),
        "latency_p90_ms": round(percentile(latencies, 90), 3),
        "latency_p99_ms": round(percentile(latencies, 99), 3),
        "latency_max_ms": round(max(latencies), 3),
        "observations_per_s": round(1 / OBS_EVERY),
    }


def _stop(children: list[subprocess.Popen]) -> None:
    """Ends the processes this benchmark started, the last first."""
    for child in reversed(children):
        child.terminate()
        try:
            child.wait(10)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait(5)


class _ObservationStream:
    """A robot's observations at OBS_EVERY on the wall clock, published by the caller's loop."""

    def __init__(self, output: Output) -> None:
        self.output = output
        self.step = 0
        self.last = 0.0

    def maybe_step(self) -> None:
        now = time.time()
        if now - self.last >= OBS_EVERY:
            self.output.put(observation(ROBOT, self.step, now))
            self.step += 1
            self.last = now


def _wait_for_arbiter(
    node: Node, stream: _ObservationStream, said: Output, timeout: float = 30.0
) -> None:
    """Until the arbiter is present and a first utterance comes back as feedback."""
    deadline = time.monotonic() + timeout
    present = False
    while not present and time.monotonic() < deadline:
        event = node.poll(0.1)
        present = isinstance(event, Presence) and event.role == "arbiter" and event.alive
    while time.monotonic() < deadline:
        stream.maybe_step()
        u = utterance(TEACHER, ROBOT, "good", onset=time.time(), confidence=1.0)
        said.put(u)
        if _wait_for_feedback(node, u.id, 0.2):
            return
    raise RuntimeError(f"the arbiter did not answer within {timeout:g} s")


def _wait_for_feedback(node: Node, source: str, timeout: float = REPLY_TIMEOUT) -> bool:
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        event = node.poll(left)
        if (
            isinstance(event, Input)
            and isinstance(event.message, CreditedFeedback)
            and source in event.message.sources
        ):
            return True
    return False


ACCURACY_CASES = [(delay, skew) for delay in (0.0, 0.5, 1.0, 1.5, 1.7, 2.0) for skew in (-5, 5)]


def credit_accuracy(steps: int = 1500, seed: int = 0) -> dict[str, float]:
    """Share of judgements credited within one step once the delay is learnt, per case,
    with TAMER's fixed 0.2-0.8 s window for comparison."""
    figures = {}
    for delay, skew in ACCURACY_CASES:
        teacher = ScriptedTeacher(delay=delay, skew=skew)
        learnt = rehearse(teacher, steps=steps, seed=seed)
        tamer = rehearse(teacher, steps=steps, seed=seed, learn=False)
        name = f"delay={delay:g}s skew={skew:+g}s"
        figures[name] = round(learnt.within_one_step(after_learning=True), 3)
        figures[f"{name} tamer"] = round(tamer.within_one_step(after_learning=False), 3)
    return figures


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--utterances", type=int, default=1000, help="arbiter: utterances timed (default 1000)"
    )


def bench_command(args: argparse.Namespace) -> int:
    result: dict = {"what": "arbiter", **measure_latency(args.utterances)}
    result["topology"] = "bench and arbiter processes, peers of a router process, loopback"
    result["credit_within_one_step"] = credit_accuracy()
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:<24} {value}")
    return 0

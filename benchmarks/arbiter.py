"""The arbiter's figures: its latency over the bus, and its credit accuracy (no bus).

- latency: from an Utterance published to its CreditedFeedback received, over zenoh on
  loopback, through the router and a `voxshape arbiter` process of a LoopbackSession, while
  observations stream in at 10 Hz (no speech recognition involved); p50, p90, p99 and the
  maximum, with the number of utterances timed and of those never answered;
- credit accuracy: a scripted teacher with a given reaction delay, delay jitter and clock skew
  judges a 10 Hz robot (voxshape/services/arbiter/scripted.py); the share of its judgements credited
  within one step of the step they reacted to, with the delay learnt (once it is) and with
  TAMER's fixed 0.2-0.8 s window, and the median error in steps; seeds are averaged.

    .venv/bin/python benchmarks/arbiter.py [--utterances 1000] [--seeds 3] [--steps 3000]
    .venv/bin/python benchmarks/arbiter.py --json --utterances 0 --jitters 0   # accuracy only
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
import uuid
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import percentile, spread
from voxshape.launcher import LoopbackSession
from voxshape.protocol import CreditedFeedback
from voxshape.runtime import Input, Node, Output, Presence
from voxshape.services.arbiter.scripted import (
    ScriptedTeacher,
    rehearse,
    scripted_observation,
    scripted_utterance,
)

ROBOT, TEACHER = "r1", "bench"
OBS_EVERY = 0.1  # seconds between observations: a person-paced session (10 Hz)
REPLY_TIMEOUT = 2.0
DELAYS = (0.0, 0.5, 1.0, 1.5, 1.7, 2.0)
SKEWS = (-5.0, 0.0, 5.0)
JITTERS = (0.0, 0.1, 0.2)
# No limit on the bench teacher's rate: it says a word as soon as the last is credited
UNLIMITED = ("--set", "utterances_per_s=1e6", "--set", "utterances_at_once=1e6")


# -- latency over the bus -------------------------------------------------------------------
def measure_latency(utterances: int = 1000, warmup_s: float = 1.2) -> dict:
    """Latency figures in milliseconds, and how many feedbacks never came."""
    with (
        tempfile.TemporaryDirectory(prefix="voxshape-bench-arbiter-") as logs,
        LoopbackSession(f"bench{uuid.uuid4().hex[:8]}", logs=Path(logs)) as session,
        Node("bench", session.client_config("bench"), quiet=True) as node,
    ):
        node.subscribe("feedback", ROBOT)
        node.watch_presence(role="arbiter")
        stream = _ObservationStream(node.advertise("obs", ROBOT))
        said = node.advertise("utterance", TEACHER)
        session.add(session.service("arbiter", *UNLIMITED))
        _wait_for_arbiter(node, stream, said)
        deadline = time.monotonic() + warmup_s
        while time.monotonic() < deadline:  # a history of steps to credit
            stream.maybe_step()
            time.sleep(OBS_EVERY / 2)
        latencies, lost = _time_utterances(node, stream, said, utterances)
    if not latencies:
        raise RuntimeError("no credited feedback came back from the arbiter")
    figures = {f"latency_p{q}_ms": round(percentile(latencies, q) or 0.0, 3) for q in (50, 90, 99)}
    return {
        "utterances": utterances,
        "lost": lost,
        "latency_n": len(latencies),
        **figures,
        "latency_max_ms": round(max(latencies), 3),
        "observations_per_s": round(1 / OBS_EVERY),
        "summary": spread(latencies, (50, 90, 99)),
    }


def _time_utterances(
    node: Node, stream: _ObservationStream, said: Output, utterances: int
) -> tuple[list[float], int]:
    """Milliseconds from each utterance published to its feedback, and how many never came."""
    latencies, lost = [], 0
    for _ in range(utterances):
        stream.maybe_step()
        u = scripted_utterance(TEACHER, ROBOT, "good", onset=time.time() - 0.3, confidence=1.0)
        t0 = time.perf_counter()
        said.put(u)
        if _wait_for_feedback(node, u.id):
            latencies.append((time.perf_counter() - t0) * 1000)
        else:
            lost += 1
    return latencies, lost


class _ObservationStream:
    """A robot's observations at OBS_EVERY on the wall clock, published by the caller's loop."""

    def __init__(self, output: Output) -> None:
        self.output = output
        self.step = 0
        self.last = 0.0

    def maybe_step(self) -> None:
        now = time.time()
        if now - self.last >= OBS_EVERY:
            self.output.put(scripted_observation(ROBOT, self.step, now))
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
        u = scripted_utterance(TEACHER, ROBOT, "good", onset=time.time(), confidence=1.0)
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


# -- credit accuracy, in process --------------------------------------------------------------
def credit_accuracy(
    delays: tuple[float, ...] = DELAYS,
    skews: tuple[float, ...] = SKEWS,
    jitters: tuple[float, ...] = JITTERS,
    seeds: int = 3,
    steps: int = 3000,
) -> list[dict]:
    """Per case (delay, jitter, skew; seconds): the share of judgements credited within one
    step once the delay is learnt, the median error (steps) and the judgements before it was
    learnt (median over seeds; -1: never), and TAMER's fixed window's share."""
    rows = []
    for jitter in jitters:
        for delay in delays:
            for skew in skews:
                learnt, errors, before, tamer = [], [], [], []
                for seed in range(seeds):
                    teacher = ScriptedTeacher(delay=delay, skew=skew, jitter=jitter)
                    run = rehearse(teacher, steps=steps, seed=seed)
                    fixed = rehearse(teacher, steps=steps, seed=seed, learn=False)
                    learnt.append(run.within_one_step())
                    errors.append(run.median_error())
                    before.append(run.learned_after if run.learned_after is not None else -1)
                    tamer.append(fixed.within_one_step(after_learning=False))
                rows.append(
                    {
                        "delay_s": delay,
                        "jitter_s": jitter,
                        "skew_s": skew,
                        "learnt_within_one_step": round(statistics.mean(learnt), 3),
                        "median_error_steps": round(statistics.median(errors), 2),
                        "judgements_before_learnt": statistics.median(before),
                        "tamer_within_one_step": round(statistics.mean(tamer), 3),
                    }
                )
    return rows


def accuracy_table(rows: list[dict]) -> str:
    lines = [
        "| delay s | jitter s | skew s | learnt: within 1 step | median error (steps) "
        "| judgements before learnt | TAMER 0.2-0.8 s: within 1 step |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['delay_s']:g} | {r['jitter_s']:g} | {r['skew_s']:+g} "
            f"| {r['learnt_within_one_step']:.3f} | {r['median_error_steps']:+.2f} "
            f"| {r['judgements_before_learnt']:g} | {r['tamer_within_one_step']:.3f} |"
        )
    return "\n".join(lines)


# -- the command ----------------------------------------------------------------------------
def _numbers(text: str) -> tuple[float, ...]:
    return tuple(float(x) for x in text.split(",") if x.strip())


def main() -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--utterances", type=int, default=1000, help="timed (0: no latency)")
    parser.add_argument("--seeds", type=int, default=3, help="accuracy: seeds averaged")
    parser.add_argument("--steps", type=int, default=3000, help="accuracy: robot steps a run")
    parser.add_argument("--delays", type=_numbers, default=DELAYS, help="seconds, e.g. 0,1.7")
    parser.add_argument("--skews", type=_numbers, default=SKEWS, help="seconds, e.g. -5,5")
    parser.add_argument("--jitters", type=_numbers, default=JITTERS, help="seconds, e.g. 0")
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    args = parser.parse_args()
    result: dict = {"what": "arbiter"}
    if args.utterances > 0:
        result["latency"] = measure_latency(args.utterances)
        result["topology"] = "bench and arbiter processes, clients of a router process, loopback"
    cases = (args.delays, args.skews, args.jitters, args.seeds, args.steps)
    result["credit"] = credit_accuracy(*cases)
    if args.json:
        print(json.dumps(result))
        return 0
    if "latency" in result:
        latency = result["latency"]
        print(
            f"utterance -> credited feedback, {result['topology']}: {latency['summary']}, "
            f"{latency['lost']} of {latency['utterances']} never answered"
        )
    print(accuracy_table(result["credit"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())

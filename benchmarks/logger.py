"""What recording a session costs: the logger's throughput, the session's step rate with and
without it, what a slow subscriber would do instead, and the size of what it writes.

    .venv/bin/python benchmarks/logger.py [--steps 3000] [--task 1]

Runs real processes on loopback in a temporary directory (LoopbackSessions: the router,
simulator in lockstep, learner, logger of compose.yaml) and prints:
- event log: records/s the logger's bus callback appends (a flood of observations over the
  router), and the append cost in-process;
- recording: records/s and steps/s the renderer draws without thinning (a replay of the
  session's event log), and what the live recording thinned;
- session step rate (simulator + learner in lockstep) without a logger, with the logger, and
  with a naive subscriber that takes 10 ms per message in zenoh's callback; one run each;
- bytes of event log and of recording per 1000 and per 10,000 steps.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import checkout_environment
from voxshape.launcher import LoopbackSession
from voxshape.launcher.topology import ServiceSpec
from voxshape.protocol import EpisodeEvent, encode
from voxshape.protocol.examples import example_messages
from voxshape.runtime import Input, Node
from voxshape.services.logger.eventlog import EventLogWriter, EventRecord, read_events
from voxshape.services.logger.recording import Recorder
from voxshape.services.logger.replay import close_stream, open_stream, render
from voxshape.services.logger.run import RunDir, session_map


def _logger(session: LoopbackSession, *extra: str) -> ServiceSpec:
    """compose.yaml's logger, serving its live recording on a port of its own."""
    return session.service("logger", "--serve-port", "0", *extra)


def session_step_rate(
    work: Path, task: str, steps: int, watcher: str
) -> tuple[float, int, RunDir | None]:
    """Simulator + learner in lockstep for `steps` steps; `watcher`: none, logger, events (a
    logger writing only its event log), or slow (a subscriber process whose callback takes
    10 ms). Returns steps/s from the simulator's own clock (its episode events), the times
    the simulator gave up waiting for an action, and the logger's run (watcher "logger")."""
    session_id = f"bench-{watcher}-{os.getpid()}"
    logs = work / "logs" / session_id
    variables = {"VOXSHAPE_TASK": task}
    with (
        LoopbackSession(session_id, variables=variables, logs=logs, cwd=work) as session,
        Node("bench", session.client_config("bench"), quiet=True) as node,
    ):
        run = _start_watcher(session, watcher, work)
        node.subscribe("episode", "r1")
        checkpoint = str(work / f"{session_id}.npz")
        session.add(
            session.service("learner", "--fresh", "--seed", "0", "--checkpoint", checkpoint)
        )
        lockstep = ("--clock", "lockstep", "--task", task, "--seed", "0")
        session.add(session.service("sim", *lockstep, "--max-steps", str(steps)))
        events = _episodes_until_done(node, session.procs["sim"], deadline_s=600)
        if watcher in ("logger", "events"):
            session.end("logger", grace=60)  # it writes its last figures as it stops
    if len(events) < 2:
        raise SystemExit(f"{watcher}: fewer than two episode events in {steps} steps")
    first, last = events[0], events[-1]
    rate = (last.step - first.step) / (last.wall_time - first.wall_time)
    stalls = re.findall(r"stopped_without_action=(\d+)", (logs / "sim.log").read_text())
    return rate, int(stalls[-1]) if stalls else 0, run


def _start_watcher(session: LoopbackSession, watcher: str, work: Path) -> RunDir | None:
    """The logger (its run, once its renderer is up), the events-only logger, a slow
    subscriber or nothing, present on the bus."""
    if watcher == "logger":
        session.add(_logger(session))
        run = RunDir(work / "runs" / session.session_id)
        deadline = time.monotonic() + 60
        while not run.recording.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)  # its renderer is up when it has opened the recording
        return run
    if watcher == "events":
        session.add(_logger(session, "--no-recording"))
    elif watcher == "slow":
        slow = [sys.executable, "-c", SLOW_SUBSCRIBER, "0.01"]
        session.add(session.client("slow", slow, environment=checkout_environment()))
    return None


def _episodes_until_done(
    node: Node, sim: subprocess.Popen, deadline_s: float
) -> list[EpisodeEvent]:
    """The simulator's episode events until it ends (its --max-steps) or `deadline_s`."""
    events: list[EpisodeEvent] = []
    deadline = time.monotonic() + deadline_s
    while sim.poll() is None and time.monotonic() < deadline:
        event = node.poll(0.2)
        if isinstance(event, Input):
            events.append(event.message)
    return events


def flood_rate(work: Path, n: int) -> tuple[float, float, dict]:
    """`n` encoded observations put as fast as zenoh takes them (BLOCK, no encoding per put) to
    a logger that only writes its event log: the publisher's rate, and the rate at which they
    arrived in the event log (from the receive times it records)."""
    session_id = f"bench-flood-{os.getpid()}"
    stats_path = RunDir(work / "runs" / session_id).receiver_stats
    with (
        LoopbackSession(session_id, logs=work / "logs" / session_id, cwd=work) as session,
        Node("bench", session.client_config("flooder"), quiet=True) as node,
    ):
        session.add(_logger(session, "--no-recording"))
        key, obs = example_messages(session_id)[0]
        payload = encode(obs)
        publisher = node.zenoh.declare_publisher(
            key, congestion_control=zenoh.CongestionControl.BLOCK, express=True
        )
        time.sleep(0.5)
        t0 = time.perf_counter()
        for _ in range(n):
            publisher.put(payload)
        sent = time.perf_counter() - t0
        deadline = time.monotonic() + 60
        stats: dict = {}
        while time.monotonic() < deadline and stats.get("received.obs", 0) < n:
            time.sleep(0.05)
            if stats_path.is_file():
                stats = json.loads(stats_path.read_text())
        publisher.undeclare()
        session.end("logger", grace=60)
    stats = json.loads(stats_path.read_text())
    times = [r.received for r in read_events(stats_path.parent / "events.msgpack").records]
    times = times[-n:]  # the observations (the first records are presence tokens)
    return n / sent, (len(times) - 1) / (times[-1] - times[0]), stats


# A subscriber of every message whose callback takes `delay` seconds, a client of the
# session its environment names (LoopbackSession.client)
SLOW_SUBSCRIBER = """
import sys, time
from voxshape.runtime import Node, bus_config
delay = float(sys.argv[1])
config = bus_config("slow")
with Node("slow", config, quiet=True) as node:
    node.zenoh.declare_subscriber(node.everything, lambda s: time.sleep(delay))
    for event in node.events():
        pass
"""


def append_cost(work: Path, n: int = 20_000) -> float:
    key, obs = example_messages("bench")[0]
    payload = encode(obs)
    with EventLogWriter(work / "append.msgpack", "bench") as writer:
        t0 = time.perf_counter()
        for i in range(n):
            writer.append(EventRecord(1.7e9 + i, key, "put", payload))
        took = time.perf_counter() - t0
    return took / n


def replay_rate(run: RunDir, work: Path) -> tuple[float, int, float]:
    """Records/s, records and seconds of rendering a session's whole event log."""
    records = read_events(run.events).records
    world = session_map(run)
    stream, _ = open_stream("bench", work / "replay.rrd", world)
    recorder = Recorder(stream, world)
    recorder.start()
    t0 = time.perf_counter()
    render(records, recorder)
    close_stream(stream)
    took = time.perf_counter() - t0
    return len(records) / took, len(records), took


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--task", default="1")
    parser.add_argument("--flood", type=int, default=20_000, help="observations in the flood")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        print(f"logger benchmark: task {args.task}, {args.steps} lockstep steps per run, "
              f"{os.cpu_count()} cores")  # fmt: skip
        us = append_cost(work) * 1e6
        print(f"event log append, in-process:        {us:.1f} us per observation")
        sent, logged, stats = flood_rate(work, args.flood)
        print(
            f"event log over the bus (flood of {args.flood} observations): published "
            f"{sent:,.0f}/s, logged {logged:,.0f}/s, {stats['received.obs']} of {args.flood}; "
            f"per sample, mean "
            f"{stats['record_us_mean']} us, max {stats['record_us_max']} us"
        )
        bare, _, _ = session_step_rate(work, args.task, args.steps, "none")
        logged_rate, _, run = session_step_rate(work, args.task, args.steps, "logger")
        events_only, _, _ = session_step_rate(work, args.task, args.steps, "events")
        slow, stalls, _ = session_step_rate(work, args.task, args.steps, "slow")
        print(f"session step rate, no logger:         {bare:,.0f} steps/s")
        print(f"session step rate, with the logger:   {logged_rate:,.0f} steps/s "
              f"(ratio {logged_rate / bare:.2f})")  # fmt: skip
        print(f"session step rate, event log only:    {events_only:,.0f} steps/s "
              f"(ratio {events_only / bare:.2f})")  # fmt: skip
        print(f"session step rate, a 10 ms subscriber: {slow:,.0f} steps/s "
              f"(ratio {slow / bare:.2f}; the simulator gave up waiting for an action "
              f"{stalls} times)")  # fmt: skip
        assert run is not None
        live = json.loads(run.recording_stats.read_text())
        receiver = json.loads(run.receiver_stats.read_text())
        steps = live.get("messages.observation", 0)
        print(
            f"live recording: {steps} observations drawn, {live['thinned_scans']} scans "
            f"thinned, max lag {live['max_lag_s']} s; logger time per sample, mean "
            f"{receiver['record_us_mean']} us"
        )
        rate, n, took = replay_rate(run, work)
        per_step = n / max(1, steps)
        print(
            f"recording without thinning (replay): {rate:,.0f} records/s = "
            f"{rate / per_step:,.0f} steps/s ({n} records, {per_step:.2f} per step, {took:.1f} s)"
        )
        events = run.events.stat().st_size
        recording = run.recording.stat().st_size
        for name, size in (("event log", events), ("recording", recording)):
            print(
                f"{name + ':':<11} {size / steps * 1000 / 1e6:.2f} MB per 1000 steps, "
                f"{size / steps * 10_000 / 1e6:.1f} MB per 10,000 steps"
            )


if __name__ == "__main__":
    main()

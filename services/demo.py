"""`voxshape demo`: the main job on the embedded default (a local session, no docker).

The full demo trains a robot by voice. Until all its services exist, it starts the ones that
do, proves the bus carries every message type through the session router, and says exactly
which services are still missing. Nothing is faked.
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from protocol import MESSAGE_TYPES, Observation, robot_key
from protocol.examples import example_messages
from services import launcher
from services.runtime import BusError, Input, Node, bus_config
from services.sim.maps import Pose, load_map
from services.sim.render import render_map

# Every service of the main job: compose service command -> what it is.
MAIN_JOB = {
    "router": "zenoh router of the session",
    "sim": "simulator: PyBullet world and robot (issue 3)",
    "learner": "learner: SARSA(lambda) with dynamic reward shaping (issue 4)",
    "speech": "speech service: vosk / pocketsphinx / mock (issue 5)",
    "arbiter": "feedback arbiter: clocks, delay credit, teachers (issue 6)",
    "logger": "logger: rerun recording and event log (issue 7)",
    "sim-teacher": "simulated teacher (issue 8)",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    launcher.add_arguments(parser)
    parser.add_argument("--rounds", type=int, default=20, help="bus check rounds per type")


def bus_check(session: launcher.Session, rounds: int) -> tuple[int, list[float]]:
    """Sends each example message `rounds` times from a second client through the router and
    waits for it on the launcher's node; returns (types that arrived, round-trip seconds)."""
    assert session.bus is not None
    receiver = session.bus
    examples = example_messages(receiver.session_id, robot="demo", teacher="demo")
    for key, _ in examples:
        receiver.input(key.rsplit("/", 1)[-1], key)
    probe_config = replace(bus_config("demo"), mode="client", connect=(session.router,))
    arrived: set[str] = set()
    trips: list[float] = []
    with Node("demo-probe", probe_config, quiet=True) as probe:
        outputs = [
            (probe.output(key.rsplit("/", 1)[-1], key), message) for key, message in examples
        ]
        time.sleep(0.2)  # let the subscriptions reach the router
        for _ in range(rounds):
            for output, message in outputs:
                t0 = time.perf_counter()
                output.put(message)
                while (event := receiver.poll(2.0)) is not None:
                    if isinstance(event, Input) and event.message.id == message.id:
                        trips.append(time.perf_counter() - t0)
                        arrived.add(event.message.TYPE)
                        break
    return len(arrived), trips


def watch_simulator(session: launcher.Session, seconds: float = 1.0) -> Observation | None:
    """Listens to the simulator's robots for a moment; draws the last pose and scan seen."""
    assert session.bus is not None
    session.bus.input("obs", robot_key(session.bus.session_id, "*", "obs"))
    seen: list[Observation] = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        event = session.bus.poll(0.1)
        if isinstance(event, Input) and isinstance(event.message, Observation):
            seen.append(event.message)
    if not seen:
        session.say(f"simulator: no observation within {seconds:g} s")
        return None
    last = seen[-1]
    out = Path("runs") / session.bus.session_id
    out.mkdir(parents=True, exist_ok=True)
    picture = out / "demo-sim.png"
    sim = next(spec for spec in session.specs if spec.command[1:2] == ("sim",))
    task = load_map(sim.environment.get("VOXSHAPE_TASK", "1"))
    pose = Pose(last.x, last.y, last.theta)
    render_map(task, pose=pose, scan=np.array(last.laser), path=picture)
    session.say(
        f"simulator: {len(seen)} observations of robot {last.robot} in {seconds:g} s "
        f"(step {last.step}, at x={last.x:.2f} y={last.y:.2f}); picture: {picture}"
    )
    return last


def run(args: argparse.Namespace) -> int:
    session = launcher.open_session(args)
    have = {spec.command[1] for spec in session.specs if len(spec.command) > 1}
    missing = [what for command, what in MAIN_JOB.items() if command not in have]
    session.say("voxshape demo: the main job trains a robot by voice in a local session.")
    code = 0
    try:
        took = session.start()
        session.say(f"session up in {took:.1f} s with: {', '.join(s.name for s in session.specs)}")
        n_types, trips = bus_check(session, args.rounds)
        ms = sorted(t * 1000 for t in trips)
        session.say(
            f"bus check: {n_types}/{len(MESSAGE_TYPES)} message types crossed the router "
            f"({len(trips)} messages), round trip p50 {statistics.median(ms):.2f} ms, "
            f"max {ms[-1]:.2f} ms"
            if ms
            else "bus check: no message arrived"
        )
        if n_types != len(MESSAGE_TYPES):
            code = 1
        if "sim" in have and watch_simulator(session) is None:
            code = 1
    except (launcher.ServiceDied, launcher.LaunchAborted, BusError) as e:
        session.say(f"error: {e}")
        code = 1
    finally:
        session.stop()
    if missing:
        session.say("not built yet, so nobody teaches the robot by voice in this demo:")
        for what in missing:
            session.say(f"  - {what}")
    return code

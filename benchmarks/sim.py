"""The simulator's speed: steps a second in one process, and in lockstep over the bus (a
`voxshape sim --clock lockstep` process answered by this one, both clients of the router of a
LoopbackSession, as in a local session), with the median time from an action sent to the
next observation received.

    .venv/bin/python benchmarks/sim.py [--task 1] [--steps 3000] [--json]
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

from voxshape.launcher import LoopbackSession
from voxshape.protocol import Action, Observation
from voxshape.runtime import Input, Node, Output
from voxshape.services.sim.task import SimConfig, Simulation
from voxshape.world.maps import load_map


def policy(obs_laser: tuple[float, ...] | list[float]) -> tuple[float, float]:
    """A trivial reactive policy: go ahead, turn left when something is close in front."""
    front = min(obs_laser[60:120])
    return (0.5, 0.0) if front > 0.8 else (0.1, 1.2)


def in_process(task: str, steps: int) -> float:
    sim = Simulation(load_map(task), seed=0)
    reading = sim.reset("r1")
    t0 = time.perf_counter()
    for _ in range(steps):
        reading = sim.step({"r1": policy(reading.laser)})["r1"]
        if reading.outcome != "running":
            reading = sim.reset("r1")
    elapsed = time.perf_counter() - t0
    sim.close()
    return steps / elapsed


def bus_lockstep(task: str, steps: int, warmup: int = 200) -> tuple[float, float, int]:
    """Steps per second of a `voxshape sim --clock lockstep` process answered by this one,
    both clients of a router process, as in a local session; the median seconds from an
    action sent to the next observation received, and of how many."""
    sim = ["--task", task, "--clock", "lockstep", "--max-steps", str(warmup + steps)]
    sim += ["--action-timeout", "5", "--seed", "0"]
    with (
        tempfile.TemporaryDirectory(prefix="voxshape-bench-sim-") as logs,
        LoopbackSession(f"bench{uuid.uuid4().hex[:8]}", logs=Path(logs)) as session,
        Node("bench", session.client_config("bench"), quiet=True) as node,
    ):
        node.subscribe("obs", "r1")
        act = node.advertise("action", "r1")
        session.add(session.service("sim", *sim))
        return _answer(node, act, warmup, steps)


def _answer(node: Node, act: Output, warmup: int, steps: int) -> tuple[float, float, int]:
    """Answers the simulator's observations with the policy's actions: steps per second after
    `warmup` steps, the median seconds from an action sent to the next observation, and the
    number of such samples."""
    answered, t0, sent_at = 0, 0.0, None
    step_times: list[float] = []  # action sent -> next observation received
    deadline = time.monotonic() + 120
    while answered < warmup + steps and time.monotonic() < deadline:
        event = node.poll(1.0)
        if not isinstance(event, Input) or not isinstance(event.message, Observation):
            continue
        obs = event.message
        if sent_at is not None and answered > warmup:
            step_times.append(time.perf_counter() - sent_at)
        sent_at = None
        if obs.outcome != "running":
            continue
        act.put(_action(obs))
        sent_at = time.perf_counter()
        answered += 1
        if answered == warmup:
            t0 = time.perf_counter()
    if answered < warmup + steps:
        raise RuntimeError(f"the simulator answered only {answered} steps in 120 s")
    rate = steps / (time.perf_counter() - t0)
    return rate, statistics.median(step_times), len(step_times)


def _action(obs: Observation) -> Action:
    """The policy's action for an observation."""
    v, omega = policy(obs.laser)
    return Action(
        robot="r1",
        episode=obs.episode,
        step=obs.step,
        discrete=None,
        v=v,
        omega=omega,
        chooser="policy",
    )


def main() -> int:
    """The simulator's figures: steps a second in one process and in lockstep over the bus."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--task", default="1")
    parser.add_argument("--steps", type=int, default=3000, help="steps measured per figure")
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    args = parser.parse_args()
    local = in_process(args.task, args.steps)
    bus, round_trip, samples = bus_lockstep(args.task, args.steps)
    result = {
        "task": args.task,
        "steps": args.steps,
        "in_process_steps_per_s": round(local, 1),
        "realtime_factor": round(local * SimConfig().control_period, 1),
        "bus_lockstep_steps_per_s": round(bus, 1),
        "bus_over_in_process": round(bus / local, 3),
        "in_process_step_ms": round(1000 / local, 3),
        "bus_action_to_next_obs_ms_p50": round(1000 * round_trip, 3),
        "bus_action_to_next_obs_n": samples,
        "topology": "sim and policy processes, clients of a router process, loopback",
    }
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:<26} {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""`voxshape bench sim`: the simulator's speed, in one process and over the bus."""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
import uuid
from dataclasses import replace
from pathlib import Path

from protocol import Action, Observation, robot_key
from services.runtime import Input, Node, Output, bus_config, free_loopback_port
from services.sim.task import SimConfig, Simulation
from services.world.maps import load_map


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--task", default="1")
    parser.add_argument("--steps", type=int, default=3000, help="steps measured per figure")


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


def bus_lockstep(task: str, steps: int, warmup: int = 200) -> tuple[float, float]:
    """Steps per second of a `voxshape sim --clock lockstep` process answered by this one,
    both peers of a router process, as in a local session; and the median seconds from an
    action sent to the next observation received."""
    session = f"bench{uuid.uuid4().hex[:8]}"
    router = f"tcp/127.0.0.1:{free_loopback_port()}"
    voxshape = str(Path(sys.executable).parent / "voxshape")
    children = [_quiet([voxshape, "router", "--session", session, "--listen", router])]
    try:
        config = replace(bus_config("bench"), session=session, connect=(router,))
        with Node("bench", config, quiet=True) as node:
            node.input("obs", robot_key(session, "r1", "obs"))
            act = node.output("action", robot_key(session, "r1", "action"))
            sim = [voxshape, "sim", "--session", session, "--connect", router, "--task", task]
            sim += ["--clock", "lockstep", "--max-steps", str(warmup + steps)]
            children.append(_quiet([*sim, "--action-timeout", "5", "--seed", "0"]))
            return _answer(node, act, warmup, steps)
    finally:
        for child in reversed(children):
            child.terminate()
            child.wait(10)


def _quiet(command: list[str]) -> subprocess.Popen:
    """A child process whose output is discarded."""
    return subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _answer(node: Node, act: Output, warmup: int, steps: int) -> tuple[float, float]:
    """Answers the simulator's observations with the policy's actions: steps per second after
    `warmup` steps, and the median seconds from an action sent to the next observation."""
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
    return steps / (time.perf_counter() - t0), statistics.median(step_times)


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


def bench_command(args: argparse.Namespace) -> int:
    """The simulator's figures: steps a second in one process and in lockstep over the bus."""
    local = in_process(args.task, args.steps)
    bus, round_trip = bus_lockstep(args.task, args.steps)
    result = {
        "task": args.task,
        "steps": args.steps,
        "in_process_steps_per_s": round(local, 1),
        "realtime_factor": round(local * SimConfig().control_period, 1),
        "bus_lockstep_steps_per_s": round(bus, 1),
        "bus_over_in_process": round(bus / local, 3),
        "in_process_step_ms": round(1000 / local, 3),
        "bus_action_to_next_obs_ms_p50": round(1000 * round_trip, 3),
        "topology": "sim and policy processes, peers of a router process, loopback",
    }
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:<26} {value}")
    return 0

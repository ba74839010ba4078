"""`voxshape sim`: the simulator on the bus, for each robot it simulates.

Its flows are its `sim` row of voxshape/protocol/dataflow.py
(`voxshape dataflow --docstring sim`).

An observation per control step (10 Hz of sim time), an episode event at each start, goal,
collision and timeout.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass
from typing import Literal

from voxshape.protocol import Action, EpisodeEvent, RobotLimits, check_id, parse_key
from voxshape.runtime import (
    ConfigError,
    Input,
    Node,
    Tick,
    add_bus_arguments,
    bus_config,
    fields,
)
from voxshape.runtime.settings import (
    add_options,
    add_settings_argument,
    option,
    read_options,
    replaced,
)
from voxshape.runtime.settings_file import write_run_settings
from voxshape.services.sim.stepper import Stepper
from voxshape.services.sim.task import SimConfig, Simulation
from voxshape.world.maps import load_map, task_option

LOCKSTEP_POLL_S = 0.05  # how often a lockstep wait checks its deadline
# Observations kept per robot for an arbiter that restarts, in wall seconds of paced steps
# (a count in lockstep): from them it rebuilds the step clock that words said meanwhile are
# credited on, so they must outlast the arbiter's utterance recovery (30 s) at any --rtf.
OBS_KEPT_S = 60.0
MAX_OBS_KEPT = 12_000


@dataclass(frozen=True)
class SimOptions:
    """`voxshape sim`'s settings (the simulation's own: SimConfig, by --set)."""

    task: str = task_option("to run")
    robots: tuple[str, ...] = option(
        ("r1",),
        "robot id, once per robot",
        flag="--robot",
        env="VOXSHAPE_ROBOTS",
        repeat=True,
        parse=lambda robot: check_id(robot, "robot"),
    )
    clock: Literal["paced", "lockstep"] = option(
        "paced",
        "paced: wall-clock time for people; lockstep: as fast as the learner answers",
        env="VOXSHAPE_CLOCK",
    )
    rtf: float = option(1.0, "paced: simulated seconds per wall second", env="VOXSHAPE_RTF")
    action_timeout: float | None = option(
        None,
        "lockstep: seconds to wait for an action (default 2); paced: seconds an action stays "
        "valid (default 0.5)",
    )
    seed: int | None = option(None, "random seed of the simulation")
    max_steps: int | None = option(None, "stop after this many steps")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    add_options(parser, SimOptions)
    add_options(parser, SimConfig)
    add_settings_argument(parser, SimConfig, "laser_noise=0.02 or rewards.goal=50")


def run(args: argparse.Namespace) -> int:
    options = read_options(SimOptions, args)
    robots = options.robots
    config = replaced(read_options(SimConfig, args), args.set)
    timeout = options.action_timeout or (2.0 if options.clock == "lockstep" else 0.5)
    if options.rtf <= 0 or timeout <= 0:
        raise ConfigError("--rtf and --action-timeout must be > 0")
    m = load_map(options.task)
    bus = bus_config("sim", args)
    write_run_settings(bus, "sim", options, config)
    sim = Simulation(m, robots, config, options.seed)
    paced = options.clock == "paced"
    period = config.control_period / options.rtf if paced else LOCKSTEP_POLL_S
    kept = min(MAX_OBS_KEPT, math.ceil(OBS_KEPT_S / period)) if paced else None
    try:
        with Node("sim", bus) as node:
            stepper = Stepper(sim, options.clock, timeout, node.counters)
            for r in robots:
                node.subscribe("action", r)
            obs = {r: node.advertise("obs", r, keep=kept) for r in robots}
            episode = {r: node.advertise("episode", r) for r in robots}
            fast, turn = config.model.max_speed, config.model.max_turn
            for r in robots:  # how fast it may be driven: the learner fits its actions to it
                node.publish(RobotLimits(robot=r, max_speed=fast, max_turn=turn))

            def publish(messages: list) -> None:
                for message in messages:
                    (episode if isinstance(message, EpisodeEvent) else obs)[message.robot].put(
                        message
                    )

            node.log.info(
                "simulating",
                extra=fields(
                    task=sim.map.name, robots=",".join(robots), clock=options.clock, rtf=options.rtf
                ),
            )
            publish(stepper.start())
            for event in node.events(tick=period):
                now = time.monotonic()
                ticked = False
                match event:
                    case Input(message=Action() as action, key=key):
                        stepper.on_action(parse_key(key).owner, action)
                    case Tick():
                        ticked = True
                if ticked if paced else stepper.ready(now):
                    publish(stepper.step(now))
                    if options.max_steps and stepper.counters["steps"] >= options.max_steps:
                        break
    finally:
        sim.close()
    return 0

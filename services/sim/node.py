"""`voxshape sim`: the simulator on the bus.

Inputs:  voxshape/<session>/robot/<robot>/action   for each robot it simulates
Outputs: voxshape/<session>/robot/<robot>/obs      one per control step (10 Hz of sim time)
         voxshape/<session>/robot/<robot>/episode  start, goal, collision, timeout
"""

from __future__ import annotations

import argparse
import math
import os
import time

from protocol import Action, EpisodeEvent, check_id, parse_key, robot_key
from services.runtime import (
    ConfigError,
    Input,
    Node,
    Tick,
    add_bus_arguments,
    bus_config,
    fields,
)
from services.runtime.settings import SettingsError, add_settings_argument, replaced
from services.sim.stepper import Stepper
from services.sim.task import SimConfig, Simulation
from services.world.maps import add_task_argument, load_map

LOCKSTEP_POLL_S = 0.05  # how often a lockstep wait checks its deadline
# Observations kept per robot for an arbiter that restarts, in wall seconds of paced steps
# (a count in lockstep): from them it rebuilds the step clock that words said meanwhile are
# credited on, so they must outlast the arbiter's utterance recovery (30 s) at any --rtf.
OBS_KEPT_S = 60.0
MAX_OBS_KEPT = 12_000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    env = os.environ.get
    add_task_argument(parser, "to run")
    parser.add_argument(
        "--robot",
        action="append",
        dest="robots",
        help="robot id, once per robot (default: VOXSHAPE_ROBOTS or r1)",
    )
    parser.add_argument(
        "--clock",
        choices=("paced", "lockstep"),
        default=env("VOXSHAPE_CLOCK", "paced"),
        help="paced: wall-clock time for people; lockstep: as fast as the "
        "learner answers (VOXSHAPE_CLOCK)",
    )
    parser.add_argument(
        "--rtf",
        type=float,
        default=float(env("VOXSHAPE_RTF", "1.0")),
        help="paced: simulated seconds per wall second (VOXSHAPE_RTF)",
    )
    parser.add_argument(
        "--action-timeout",
        type=float,
        default=None,
        help="lockstep: seconds to wait for an action (default 2); paced: "
        "seconds an action stays valid (default 0.5)",
    )
    parser.add_argument(
        "--collision",
        choices=("end", "continue"),
        default=SimConfig.collision,
        help="a collision costs a penalty and goes on (default), or ends the episode",
    )
    add_settings_argument(
        parser, "SimConfig (services/sim/task.py)", "laser_noise=0.02 or rewards.goal=50"
    )
    parser.add_argument("--seed", type=int, default=None)
    parser.add_argument("--max-steps", type=int, default=None, help="stop after this many steps")


def run(args: argparse.Namespace) -> int:
    robots = tuple(args.robots or os.environ.get("VOXSHAPE_ROBOTS", "r1").split(","))
    try:
        config = replaced(SimConfig(collision=args.collision), args.set)
    except SettingsError as e:
        raise ConfigError(str(e)) from None
    timeout = args.action_timeout or (2.0 if args.clock == "lockstep" else 0.5)
    if args.rtf <= 0 or timeout <= 0:
        raise ConfigError("--rtf and --action-timeout must be > 0")
    for robot in robots:
        check_id(robot, "robot")
    m = load_map(args.task)
    bus = bus_config("sim", args)
    sim = Simulation(m, robots, config, args.seed)
    period = config.control_period / args.rtf if args.clock == "paced" else LOCKSTEP_POLL_S
    kept = min(MAX_OBS_KEPT, math.ceil(OBS_KEPT_S / period)) if args.clock == "paced" else None
    try:
        with Node("sim", bus) as node:
            stepper = Stepper(sim, args.clock, timeout, node.counters)
            for r in robots:
                node.input("action", robot_key(node.session_id, r, "action"))
            obs = {
                r: node.output("obs", robot_key(node.session_id, r, "obs"), keep=kept)
                for r in robots
            }
            episode = {
                r: node.output("episode", robot_key(node.session_id, r, "episode")) for r in robots
            }

            def publish(messages: list) -> None:
                for message in messages:
                    (episode if isinstance(message, EpisodeEvent) else obs)[message.robot].put(
                        message
                    )

            node.log.info(
                "simulating",
                extra=fields(
                    task=sim.map.name, robots=",".join(robots), clock=args.clock, rtf=args.rtf
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
                if ticked if args.clock == "paced" else stepper.ready(now):
                    publish(stepper.step(now))
                    if args.max_steps and stepper.counters["steps"] >= args.max_steps:
                        break
    finally:
        sim.close()
    return 0

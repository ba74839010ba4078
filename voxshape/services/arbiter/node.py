"""`voxshape arbiter`: the feedback arbiter on the bus (the core is arbiter.py).

Its flows are its `arbiter` row of voxshape/protocol/dataflow.py
(`voxshape dataflow --docstring arbiter`).

From the robots' observations it takes their step timing, bumps, goals and episodes; a
robot's question is answered by the next word said to it; teachers' utterances become
credited rewards and commands for the learners, with interventions per episode and teacher
statistics, and each teacher hears what was understood, or why not.

Nothing a teacher gives is lost to a restart: utterances are a recovering input (what kept
teacher outputs published while the router restarted is fetched again; copies are dropped by
id), and feedback is a kept output, so a learner that was down gets what it missed when it is
back (it skips, by id, what it took before).
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from voxshape.protocol import (
    ClockProbe,
    CreditedFeedback,
    HelpRequest,
    Message,
    Observation,
    TeacherNotice,
    Utterance,
    load_vocabulary,
    parse_key,
)
from voxshape.runtime import Input, Node, Tick, add_bus_arguments, bus_config, fields
from voxshape.runtime.logs import worth_logging
from voxshape.runtime.settings import (
    add_options,
    add_settings_argument,
    option,
    read_options,
    replaced,
)
from voxshape.runtime.settings_file import write_run_settings
from voxshape.services.arbiter.arbiter import Arbiter
from voxshape.services.arbiter.config import ArbiterConfig

TICK = 0.1  # seconds: merge windows and statistics are checked this often
# A (re)joining arbiter recovers the robots' steps and the utterances of the last 30 s (as
# much as it remembers of the steps; voxshape/protocol/dataflow.py), and asks again this long after
# joining, in case zenoh's own query came back empty: the copies are told apart, and the
# words recovered are held until then (STARTING_S, 3 s).
REFETCH_AFTER_S = 1.0


@dataclass(frozen=True)
class ArbiterOptions:
    """`voxshape arbiter`'s own settings (the arbitration's: ArbiterConfig)."""

    vocabulary: Path | None = option(
        None, "vocabulary file", env="VOXSHAPE_VOCABULARY", show="built in"
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    add_options(parser, ArbiterOptions)
    add_options(parser, ArbiterConfig)
    add_settings_argument(parser, ArbiterConfig, "settle=5")


def config_from(args: argparse.Namespace, env: Mapping[str, str] = os.environ) -> ArbiterConfig:
    """ArbiterConfig's defaults, its fields' flags (or variables), then the --set settings."""
    return replaced(read_options(ArbiterConfig, args, env), args.set)


def run(args: argparse.Namespace) -> int:
    config = config_from(args)
    options = read_options(ArbiterOptions, args)
    vocabulary = load_vocabulary(options.vocabulary)
    arbiter = Arbiter(config, vocabulary, started_at=time.time())
    bus = bus_config("arbiter", args)
    write_run_settings(bus, "arbiter", options, config)
    with Node("arbiter", bus) as node:
        node.subscribe("obs")  # recovered
        node.subscribe("utterance")  # recovered
        node.subscribe("clock")
        node.subscribe("help")
        node.log.info(
            "arbitrating",
            extra=fields(
                meanings=len(vocabulary.meanings),
                min_confidence=config.min_confidence,
                delay=str(config.delay),
                learning=config.learning.enabled,
                merge=config.merge,
            ),
        )
        refetch_at = time.monotonic() + REFETCH_AFTER_S
        for event in node.events(tick=TICK):
            if refetch_at and time.monotonic() >= refetch_at:
                node.fetch_history("obs")
                node.fetch_history("utterance")
                refetch_at = 0.0
            try:
                for message in _handle(arbiter, event):
                    node.publish(message)
                    _log_outgoing(node, message)
            except Exception as e:  # a bug met by some input: said loudly, the service goes on
                node.counters["arbiter.errors"] += 1
                if worth_logging(node.counters["arbiter.errors"]):
                    node.log.exception("failed to handle an event", extra=fields(error=repr(e)))
            if isinstance(event, Tick):
                _copy_counters(arbiter, node)
        for message in arbiter.flush():
            node.publish(message)
        _copy_counters(arbiter, node)
    return 0


def _copy_counters(arbiter: Arbiter, node: Node) -> None:
    for name, value in arbiter.counters.items():
        node.counters[f"arbiter.{name}"] = value


def _handle(arbiter: Arbiter, event: object) -> list[Message]:
    received = time.time()
    match event:
        case Input(message=Observation() as obs):
            return arbiter.on_observation(obs, received)
        case Input(key=key, message=HelpRequest() as request):
            if parse_key(key).owner != request.robot:  # a question on another robot's key
                arbiter.counters["rejected.robot_mismatch"] += 1
                return []
            return arbiter.on_help(request, received)
        case Input(key=key, message=Utterance() as said):
            return arbiter.on_utterance(said, received, parse_key(key).owner)
        case Input(key=key, message=ClockProbe() as probe):
            return arbiter.on_clock_probe(probe, received, time.time(), parse_key(key).owner)
        case Tick():
            return arbiter.on_tick(received)
    return []


def _log_outgoing(node: Node, message: Message) -> None:
    if isinstance(message, TeacherNotice) and message.kind != "understood":
        node.counters[f"notice.{message.kind}"] += 1
        if worth_logging(node.counters[f"notice.{message.kind}"]):
            node.log.info(
                "utterance ignored",
                extra=fields(
                    reason=message.kind,
                    teacher=message.teacher,
                    robot=message.robot,
                    text=message.text,
                ),
            )
    elif isinstance(message, CreditedFeedback):
        node.log.debug(
            "feedback",
            extra=fields(
                robot=message.robot,
                kind=message.kind,
                reward=message.reward,
                command=message.command,
                steps=",".join(f"{c.step}:{c.weight:.2f}" for c in message.credits),
                teachers=",".join(message.teachers),
            ),
        )

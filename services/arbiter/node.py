"""`voxshape arbiter`: the feedback arbiter on the bus (the core is arbiter.py).

Inputs:  voxshape/<session>/robot/*/obs               step timing, bumps, goals, episodes
         voxshape/<session>/robot/*/help              a robot's question: the next word answers it
         voxshape/<session>/teacher/*/utterance       what teachers said
         voxshape/<session>/teacher/*/clock           teachers' clock probes
Outputs: voxshape/<session>/robot/<robot>/feedback    credited rewards and commands -> learner
         voxshape/<session>/robot/<robot>/teaching    interventions per episode, teacher stats
         voxshape/<session>/robot/<robot>/answer      who answered a question, with what
         voxshape/<session>/teacher/<teacher>/notice  understood, or why not -> teacher client
         voxshape/<session>/teacher/<teacher>/clock-reply

Nothing a teacher gives is lost to a restart: utterances are a recovering input (what kept
teacher outputs published while the router restarted is fetched again; copies are dropped by
id), and feedback is a kept output, so a learner that was down gets what it missed when it is
back (it skips, by id, what it took before).
"""

from __future__ import annotations

import argparse
import os
import time

from protocol import (
    ClockProbe,
    ClockReply,
    CreditedFeedback,
    HelpAnswer,
    HelpRequest,
    Message,
    Observation,
    TeacherNotice,
    TeachingStats,
    Utterance,
    load_vocabulary,
    parse_key,
    robot_key,
    teacher_key,
)
from services.arbiter.arbiter import Arbiter
from services.arbiter.config import (
    MERGE_POLICIES,
    ArbiterConfig,
    ArbiterConfigError,
    parse_per_teacher,
    parse_teachers,
    parse_window,
)
from services.runtime import Input, Node, Output, Tick, add_bus_arguments, bus_config, fields
from services.runtime.logs import worth_logging
from services.runtime.settings import SettingsError, add_settings_argument, replaced

TICK = 0.1  # seconds: merge windows and statistics are checked this often
# A (re)joining arbiter recovers the robots' steps and the utterances of the last 30 s (as
# much as it remembers of the steps; protocol/dataflow.py), and asks again this long after
# joining, in case zenoh's own query came back empty: the copies are told apart, and the
# words recovered are held until then (STARTING_S, 3 s).
REFETCH_AFTER_S = 1.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    env = os.environ.get
    defaults = ArbiterConfig()
    parser.add_argument(
        "--vocabulary",
        default=env("VOXSHAPE_VOCABULARY"),
        help="vocabulary file (default: built in)",
    )
    parser.add_argument(
        "--min-confidence",
        type=float,
        default=defaults.min_confidence,
        help="ignore utterances recognized with less (the teacher is asked to repeat)",
    )
    parser.add_argument(
        "--delay",
        default=f"{defaults.delay.lo:g}:{defaults.delay.hi:g}",
        help="LO:HI seconds before the onset in which teachers saw what they judge, until "
        "their own delay is learnt (default: TAMER's 0.2:0.8)",
    )
    parser.add_argument(
        "--teacher-delay",
        action="append",
        metavar="TEACHER=LO:HI",
        help="one teacher's window (repeatable)",
    )
    parser.add_argument(
        "--robot-time",
        action="append",
        default=[t for t in os.environ.get("VOXSHAPE_ROBOT_TIME", "").split(",") if t],
        metavar="TEACHER",
        help="a teacher whose delays and rate are robot seconds: a simulated teacher on a "
        "simulator faster than real time (repeatable, or comma-separated in "
        "VOXSHAPE_ROBOT_TIME; people react in their own seconds)",
    )
    parser.add_argument(
        "--merge",
        choices=MERGE_POLICIES,
        default=env("VOXSHAPE_MERGE", defaults.merge),
        help="several teachers: sum (at once), mean or majority within merge_window "
        "(VOXSHAPE_MERGE)",
    )
    parser.add_argument(
        "--teacher-weight", action="append", metavar="TEACHER=W", help="(repeatable; default 1)"
    )
    add_settings_argument(parser, "ArbiterConfig (services/arbiter/config.py)", "settle=5")


def config_from(args: argparse.Namespace) -> ArbiterConfig:
    """The flags over ArbiterConfig's defaults, then the --set settings."""
    flags = ArbiterConfig(
        min_confidence=args.min_confidence,
        delay=parse_window(args.delay),
        teacher_delay=parse_per_teacher(
            args.teacher_delay, parse_window, "--teacher-delay", "ana=0.5:1.2"
        ),
        robot_time=parse_teachers(args.robot_time, "--robot-time"),
        merge=args.merge,
        teacher_weight=parse_per_teacher(args.teacher_weight, float, "--teacher-weight", "ana=2"),
    )
    try:
        return replaced(flags, args.set)
    except SettingsError as e:
        raise ArbiterConfigError(str(e)) from None


class _Publisher:
    """One output per key, declared on first use (robots and teachers come and go)."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self._outputs: dict[str, Output] = {}

    def put(self, message: Message) -> None:
        session = self.node.session_id
        match message:
            case CreditedFeedback():
                name, key = "feedback", robot_key(session, message.robot, "feedback")
            case TeachingStats():
                name, key = "teaching", robot_key(session, message.robot, "teaching")
            case HelpAnswer():
                name, key = "answer", robot_key(session, message.robot, "answer")
            case TeacherNotice():
                name, key = "notice", teacher_key(session, message.teacher, "notice")
            case ClockReply():
                name, key = "clock-reply", teacher_key(session, message.teacher, "clock-reply")
            case _:
                raise TypeError(f"the arbiter does not publish {type(message).__name__}")
        output = self._outputs.get(key)
        if output is None:
            output = self._outputs[key] = self.node.output(name, key)  # feedback kept
        output.put(message)


def run(args: argparse.Namespace) -> int:
    config = config_from(args)
    vocabulary = load_vocabulary(args.vocabulary)
    arbiter = Arbiter(config, vocabulary, started_at=time.time())
    with Node("arbiter", bus_config("arbiter", args)) as node:
        publish = _Publisher(node)
        node.input("obs", robot_key(node.session_id, "*", "obs"))  # recovered
        node.input("utterance", teacher_key(node.session_id, "*", "utterance"))  # recovered
        node.input("clock", teacher_key(node.session_id, "*", "clock"))
        node.input("help", robot_key(node.session_id, "*", "help"))
        node.log.info(
            "arbitrating",
            extra=fields(
                meanings=len(vocabulary.meanings),
                min_confidence=config.min_confidence,
                delay=args.delay,
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
                    publish.put(message)
                    _log_outgoing(node, message)
            except Exception as e:  # a bug met by some input: said loudly, the service goes on
                node.counters["arbiter.errors"] += 1
                if worth_logging(node.counters["arbiter.errors"]):
                    node.log.exception("failed to handle an event", extra=fields(error=repr(e)))
            if isinstance(event, Tick):
                _copy_counters(arbiter, node)
        for message in arbiter.flush():
            publish.put(message)
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

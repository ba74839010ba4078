"""`voxshape learner`: the learner on the bus, one robot.

Inputs:  voxshape/<session>/robot/<robot>/obs        the simulator's observations
         voxshape/<session>/robot/<robot>/feedback   credited rewards and commands (arbiter)
Outputs: voxshape/<session>/robot/<robot>/action     one per observation that is not terminal
         voxshape/<session>/robot/<robot>/learning   a summary per step (for the logger)
Checkpoints every `--checkpoint-every` seconds and on shutdown; restored on start.

Feedback is a recovering input of the arbiter's kept output: what was published while this
learner was down (killed, restarting) is delivered when it is back, and feedback taken before
(its id is in the checkpoint) is skipped, so each piece is taken exactly once.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from protocol import CreditedFeedback, Observation, check_id, robot_key
from services.learner import checkpoint
from services.learner.config import add_settings_argument, with_settings
from services.learner.online import OnlineLearner
from services.learner.sarsa import Learner
from services.learner.traces import TraceBook
from services.runtime import ConfigError, Input, Node, add_bus_arguments, bus_config, fields
from services.runtime.logs import worth_logging

# Seconds of the arbiter's kept feedback a (re)starting learner asks for: older feedback is
# about steps long out of its window, and what it took before is skipped by id.
FEEDBACK_RECOVERY_S = 60.0
MAX_PENDING = 100_000  # messages looked through for feedback when stopping


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    parser.add_argument(
        "--robot",
        default=os.environ.get("VOXSHAPE_ROBOT", "r1"),
        help="the robot it drives (VOXSHAPE_ROBOT)",
    )
    parser.add_argument(
        "--checkpoint",
        type=Path,
        help="checkpoint file (default: runs/<session>/learner-<robot>.npz)",
    )
    parser.add_argument("--checkpoint-every", type=float, default=10.0, help="seconds")
    parser.add_argument("--fresh", action="store_true", help="ignore an existing checkpoint")
    parser.add_argument("--traces", type=Path, help="initial traces to learn from first")
    parser.add_argument("--seed", type=int, default=None)
    add_settings_argument(parser)


def run(args: argparse.Namespace) -> int:
    robot = check_id(args.robot, "robot")
    bus = bus_config("learner", args)
    path = args.checkpoint or Path("runs") / bus.session / f"learner-{robot}.npz"
    config = with_settings(args.set)
    try:
        resumed = None if args.fresh else checkpoint.resume(path, config, args.seed)
    except checkpoint.CheckpointError as e:
        raise ConfigError(f"{e}. To start over, run with --fresh (it overwrites it).") from None
    learner, bookmark = resumed or (Learner(config, args.seed), checkpoint.Bookmark())
    with Node("learner", bus) as node:
        node.log.info(
            "learning",
            extra=fields(
                robot=robot,
                checkpoint=path,
                states=len(learner.states),
                episodes=learner.episode,
                resumed_at_step=bookmark.step if bookmark.step is not None else "-",
                feedback_taken=len(bookmark.taken),
            ),
        )
        initial = TraceBook.load(args.traces) if args.traces else None
        if initial and not initial.headings and learner.config.goal_sectors:
            node.log.warning(
                "initial traces without headings: replayed facing 0 rad, so their goal "
                "sectors are wrong; record them again (headings are saved now), or run "
                "with --set goal_sectors=0",
                extra=fields(traces=args.traces),
            )
        if initial:
            replayed = initial.replay(learner)
            node.log.info("learnt from initial traces", extra=fields(steps=replayed))
        online = OnlineLearner(learner, bookmark, initial, node.counters)
        node.input("obs", robot_key(node.session_id, robot, "obs"))
        node.input(
            "feedback", robot_key(node.session_id, robot, "feedback"), recover=FEEDBACK_RECOVERY_S
        )
        act = node.output("action", robot_key(node.session_id, robot, "action"))
        summary = node.output(
            "learning", robot_key(node.session_id, robot, "learning"), must_arrive=False
        )
        last_save = time.monotonic()
        for event in node.events(tick=1.0):
            match event:
                case Input(message=Observation() as obs):
                    action, learnt = online.observe(obs)
                    if action is not None:
                        act.put(action)
                    summary.put(learnt)
                case Input(message=CreditedFeedback() as feedback):
                    _log_dropped(node, feedback, online.take(feedback))
            if time.monotonic() - last_save >= args.checkpoint_every:
                checkpoint.save(learner, path, bookmark)
                last_save = time.monotonic()
        for _ in range(MAX_PENDING):  # feedback that arrived before the stop is taken too
            match node.poll(0):
                case None:
                    break
                case Input(message=CreditedFeedback() as feedback):
                    _log_dropped(node, feedback, online.take(feedback))
        checkpoint.save(learner, path, bookmark)
        if online.book.episodes:
            online.book.save(path.with_name(f"traces-{robot}.npz"))
        node.counters.update({f"learner.{k}": v for k, v in learner.counters.items()})
    return 0


def _log_dropped(node: Node, feedback: CreditedFeedback, dropped: list[int]) -> None:
    if dropped and worth_logging(node.counters["learner.feedback_partly_dropped"]):
        node.log.warning(
            "feedback for steps outside the window dropped",
            extra=fields(
                steps=f"{min(dropped)}..{max(dropped)}",
                of_credits=f"{len(dropped)}/{len(feedback.credits)}",
                teachers=",".join(feedback.teachers),
            ),
        )

"""`voxshape learner`: the learners on the bus, one per robot, in one process.

Inputs:  voxshape/<session>/robot/<robot>/obs        the simulator's observations
         voxshape/<session>/robot/<robot>/feedback   credited rewards and commands (arbiter)
Outputs: voxshape/<session>/robot/<robot>/action     one per observation that is not terminal
         voxshape/<session>/robot/<robot>/learning   a summary per step (for the logger)
         voxshape/<session>/robot/<robot>/help       "which way?" when it is lost (asking.py)
for each robot it drives (`--robot`, once per robot, or VOXSHAPE_ROBOTS, as the simulator).
Each robot has its own SARSA(lambda) learner and checkpoint, saved every
`--checkpoint-every` seconds and on shutdown, restored on start.

Feedback is a recovering input of the arbiter's kept output: what was published while this
learner was down (killed, restarting) is delivered when it is back, and feedback taken before
(its id is in the checkpoint) is skipped, so each piece is taken exactly once.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from protocol import CreditedFeedback, Observation, check_id, parse_key, robot_key
from services.learner import checkpoint
from services.learner.config import LearnerConfig, add_settings_argument, with_settings
from services.learner.online import OnlineLearner
from services.learner.sarsa import Learner
from services.learner.traces import TraceBook
from services.runtime import (
    ConfigError,
    Input,
    Node,
    Output,
    add_bus_arguments,
    bus_config,
    fields,
)
from services.runtime.logs import worth_logging
from services.world.maps import add_task_argument, load_map

MAX_PENDING = 100_000  # messages looked through for feedback when stopping
ROBOT_FIELD = "{robot}"  # in --checkpoint: the robot's id


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    parser.add_argument(
        "--robot",
        action="append",
        dest="robots",
        help="a robot it drives, once per robot (default: VOXSHAPE_ROBOTS, a comma list as "
        "the simulator's, else VOXSHAPE_ROBOT, else r1)",
    )
    parser.add_argument(
        "--checkpoint",
        type=Path,
        help=f"checkpoint file, {ROBOT_FIELD} standing for the robot (default: "
        f"runs/<session>/learner-{ROBOT_FIELD}.npz)",
    )
    parser.add_argument("--checkpoint-every", type=float, default=10.0, help="seconds")
    parser.add_argument("--fresh", action="store_true", help="ignore existing checkpoints")
    parser.add_argument("--traces", type=Path, help="initial traces to learn from first")
    parser.add_argument(
        "--seed", type=int, default=None, help="random seed (the n-th robot's learner: seed + n)"
    )
    add_task_argument(parser, "for its episodes' timeout (when the robot asks for help)")
    add_settings_argument(parser)


def robots_of(given: list[str] | None, environ: Mapping[str, str] = os.environ) -> tuple[str, ...]:
    """The robots to drive: --robot flags, else VOXSHAPE_ROBOTS, else VOXSHAPE_ROBOT, else r1
    (checked ids, without repeats)."""
    listed = given or environ.get("VOXSHAPE_ROBOTS", "").split(",")
    robots = [r.strip() for r in listed if r.strip()] or [environ.get("VOXSHAPE_ROBOT") or "r1"]
    return tuple(dict.fromkeys(check_id(r, "robot") for r in robots))


def checkpoint_path(template: Path | None, session: str, robot: str, robots: int) -> Path:
    """Where a robot's learner is checkpointed: runs/<session>/learner-<robot>.npz, or
    --checkpoint (which must name the robot when there are several)."""
    if template is None:
        return Path("runs") / session / f"learner-{robot}.npz"
    if ROBOT_FIELD not in str(template) and robots > 1:
        raise ConfigError(
            f"--checkpoint {template} with {robots} robots: put {ROBOT_FIELD} in it "
            f"(e.g. learner-{ROBOT_FIELD}.npz) so that each robot has its own"
        )
    return Path(str(template).replace(ROBOT_FIELD, robot))


@dataclass
class Driven:
    """One robot's learner in this process: its checkpoint, its progress, its outputs."""

    robot: str
    path: Path
    learner: Learner
    bookmark: checkpoint.Bookmark
    online: OnlineLearner
    act: Output
    summary: Output
    ask: Output

    def save(self) -> None:
        checkpoint.save(self.learner, self.path, self.bookmark)


def restore(
    path: Path, config: LearnerConfig, seed: int | None, fresh: bool
) -> tuple[Learner, checkpoint.Bookmark]:
    """The learner saved at `path` and its bookmark, or a new one."""
    try:
        resumed = None if fresh else checkpoint.resume(path, config, seed)
    except checkpoint.CheckpointError as e:
        raise ConfigError(f"{e}. To start over, run with --fresh (it overwrites it).") from None
    return resumed or (Learner(config, seed), checkpoint.Bookmark())


def run(args: argparse.Namespace) -> int:
    robots = robots_of(args.robots)
    bus = bus_config("learner", args)
    paths = {r: checkpoint_path(args.checkpoint, bus.session, r, len(robots)) for r in robots}
    config = with_settings(args.set)
    restored = {
        r: restore(paths[r], config, None if args.seed is None else args.seed + i, args.fresh)
        for i, r in enumerate(robots)
    }
    with Node("learner", bus) as node:
        timeout_s = load_map(args.task).timeout
        driven = {r: drive(node, r, paths[r], *restored[r], args.traces, timeout_s) for r in robots}
        last_save = time.monotonic()
        for event in node.events(tick=1.0):
            match event:
                case Input(message=Observation() as obs, key=key):
                    one = driven[parse_key(key).owner]
                    action, learnt, question = one.online.observe(obs)
                    if action is not None:
                        one.act.put(action)
                    one.summary.put(learnt)
                    if question is not None:
                        one.ask.put(question)
                case Input(message=CreditedFeedback() as feedback, key=key):
                    one = driven[parse_key(key).owner]
                    _log_dropped(node, feedback, one.online.take(feedback))
            if time.monotonic() - last_save >= args.checkpoint_every:
                for one in driven.values():
                    one.save()
                last_save = time.monotonic()
        for _ in range(MAX_PENDING):  # feedback that arrived before the stop is taken too
            match node.poll(0):
                case None:
                    break
                case Input(message=CreditedFeedback() as feedback, key=key):
                    one = driven[parse_key(key).owner]
                    _log_dropped(node, feedback, one.online.take(feedback))
        for one in driven.values():
            one.save()
            if one.online.book.episodes:
                one.online.book.save(one.path.with_name(f"traces-{one.robot}.npz"))
            node.counters.update({f"learner.{k}": v for k, v in one.learner.counters.items()})
    return 0


def drive(
    node: Node,
    robot: str,
    path: Path,
    learner: Learner,
    bookmark: checkpoint.Bookmark,
    traces: Path | None,
    timeout_s: float,
) -> Driven:
    """Puts one robot's learner on the bus: its initial traces learnt, its inputs and
    outputs declared."""
    node.log.info(
        "learning",
        extra=fields(
            robot=robot,
            checkpoint=path,
            states=len(learner.features),
            episodes=learner.episode,
            resumed_at_step=bookmark.step if bookmark.step is not None else "-",
            feedback_taken=len(bookmark.taken),
        ),
    )
    initial = TraceBook.load(traces) if traces else None
    if initial and not initial.poses:
        node.log.warning(
            "initial traces saved without the robot's position: replayed at (0, 0), so "
            "they teach the wrong places; record them again (poses are saved now), or run "
            "with --set representation=keys",
            extra=fields(traces=traces),
        )
    if initial:
        replayed = initial.replay(learner)
        node.log.info("learnt from initial traces", extra=fields(robot=robot, steps=replayed))
    online = OnlineLearner(learner, bookmark, initial, node.counters, timeout_s)
    node.input("obs", robot_key(node.session_id, robot, "obs"))
    node.input("feedback", robot_key(node.session_id, robot, "feedback"))
    act = node.output("action", robot_key(node.session_id, robot, "action"))
    summary = node.output(
        "learning", robot_key(node.session_id, robot, "learning"), must_arrive=False
    )
    ask = node.output("help", robot_key(node.session_id, robot, "help"))
    return Driven(robot, path, learner, bookmark, online, act, summary, ask)


def _log_dropped(node: Node, feedback: CreditedFeedback, dropped: list[int]) -> None:
    if dropped and worth_logging(node.counters["learner.feedback_partly_dropped"]):
        node.log.warning(
            "feedback for steps outside the window dropped",
            extra=fields(
                robot=feedback.robot,
                steps=f"{min(dropped)}..{max(dropped)}",
                of_credits=f"{len(dropped)}/{len(feedback.credits)}",
                teachers=",".join(feedback.teachers),
            ),
        )

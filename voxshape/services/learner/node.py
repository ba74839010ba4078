"""`voxshape learner`: the learners on the bus, one per robot, in one process.

Its flows are its `learner` row of voxshape/protocol/dataflow.py
(`voxshape dataflow --docstring learner`).

For each robot it drives (`--robot`, once per robot, or VOXSHAPE_ROBOTS, as the simulator):
an action per observation that is not terminal, a summary per step (for the logger), and
"which way?" when it is lost (asking.py).
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
from dataclasses import dataclass, replace
from pathlib import Path

from voxshape.protocol import (
    CreditedFeedback,
    Observation,
    RobotLimits,
    check_id,
    parse_key,
)
from voxshape.runtime import (
    ConfigError,
    Input,
    Node,
    Output,
    add_bus_arguments,
    bus_config,
    fields,
)
from voxshape.runtime.logs import worth_logging
from voxshape.runtime.settings import add_options, option, read_options, write_settings
from voxshape.services.learner import checkpoint
from voxshape.services.learner.config import LearnerConfig, add_settings_argument, with_settings
from voxshape.services.learner.online import OnlineLearner
from voxshape.services.learner.sarsa import Learner
from voxshape.services.learner.traces import TraceBook
from voxshape.world.maps import Map, load_map, task_option

MAX_PENDING = 100_000  # messages looked through for feedback when stopping
ROBOT_FIELD = "{robot}"  # in --checkpoint: the robot's id


@dataclass(frozen=True)
class LearnerOptions:
    """`voxshape learner`'s settings (the learner's own: LearnerConfig, by --set)."""

    robots: tuple[str, ...] = option(
        (),
        "a robot it drives, once per robot (default: VOXSHAPE_ROBOTS, a comma list as the "
        "simulator's, else VOXSHAPE_ROBOT, else r1)",
        flag="--robot",
        repeat=True,
    )
    checkpoint: Path | None = option(
        None,
        f"checkpoint file, {ROBOT_FIELD} standing for the robot (default: "
        f"runs/<session>/learner-{ROBOT_FIELD}.npz)",
        parse=Path,
    )
    checkpoint_every: float = option(10.0, "seconds between checkpoints")
    fresh: bool = option(False, "ignore existing checkpoints")
    traces: Path | None = option(None, "initial traces to learn from first", parse=Path)
    seed: int | None = option(None, "random seed (the n-th robot's learner: seed + n)")
    task: str = task_option(
        "for its episodes' timeout (when the robot asks for help), and potential=oracle's map"
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    add_options(parser, LearnerOptions)
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

    scale: float = 1.0  # of every velocity it sends, to fit the robot's limits
    fitted: bool = False  # the robot's limits were asked for (or came)

    def save(self) -> None:
        checkpoint.save(self.learner, self.path, self.bookmark)

    def fit(self, limits: RobotLimits) -> float:
        """Scales its actions' velocities to the robot's limits (v and omega alike, so that
        each action keeps its path, slower): nothing it sends is clipped. The new scale."""
        velocities = self.learner.config.velocities.values()
        top_v = max(abs(v) for v, _ in velocities) or 1.0
        top_omega = max(abs(omega) for _, omega in velocities) or 1.0
        self.scale = min(1.0, limits.max_speed / top_v, limits.max_turn / top_omega)
        self.fitted = True
        return self.scale

    def observe(self, obs: Observation) -> None:
        """Learns from the step, then publishes the next action, the summary and a
        question, if any."""
        action, learnt, question = self.online.observe(obs)
        if action is not None and action.v is not None and self.scale < 1.0:
            action = replace(action, v=action.v * self.scale, omega=action.omega * self.scale)
        if action is not None:
            self.act.put(action)
        self.summary.put(learnt)
        if question is not None:
            self.ask.put(question)

    def hear(self, node: Node, feedback: CreditedFeedback) -> None:
        """A credited word: the agent takes it (once), then what it could not credit (its
        steps had left the window) is logged."""
        dropped = self.online.take(feedback)
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


def restore(
    path: Path, config: LearnerConfig, seed: int | None, fresh: bool, task: Map
) -> tuple[Learner, checkpoint.Bookmark]:
    """The learner saved at `path` and its bookmark, or a new one."""
    try:
        resumed = None if fresh else checkpoint.resume(path, config, seed, task)
    except checkpoint.CheckpointError as e:
        raise ConfigError(f"{e}. To start over, run with --fresh (it overwrites it).") from None
    return resumed or (Learner(config, seed, task), checkpoint.Bookmark())


def run(args: argparse.Namespace) -> int:
    options = read_options(LearnerOptions, args)
    robots = robots_of(list(options.robots) or None)
    bus = bus_config("learner", args)
    paths = {r: checkpoint_path(options.checkpoint, bus.session, r, len(robots)) for r in robots}
    config = with_settings(args.set)
    write_settings(paths[robots[0]].parent, "learner", config)  # the run's, on record
    seeds = {r: None if options.seed is None else options.seed + i for i, r in enumerate(robots)}
    task = load_map(options.task)
    restored = {r: restore(paths[r], config, seeds[r], options.fresh, task) for r in robots}
    with Node("learner", bus) as node:
        timeout_s = task.timeout
        driven = {
            r: drive(node, r, paths[r], *restored[r], options.traces, timeout_s) for r in robots
        }
        last_save = time.monotonic()
        for event in node.events(tick=1.0):
            match event:
                case Input(message=Observation() as obs, key=key):
                    one = driven[parse_key(key).owner]
                    if not one.fitted:  # before its first action: its limits may come later
                        limits = node.latest("limits", one.robot)
                        fit(node, one, limits)
                    one.observe(obs)
                case Input(message=CreditedFeedback() as feedback, key=key):
                    driven[parse_key(key).owner].hear(node, feedback)
                case Input(message=RobotLimits() as limits, key=key):
                    fit(node, driven[parse_key(key).owner], limits)
            if time.monotonic() - last_save >= options.checkpoint_every:
                for one in driven.values():
                    one.save()
                last_save = time.monotonic()
        for event in node.pending(MAX_PENDING):  # feedback that came before the stop, too
            if isinstance(event, Input) and isinstance(event.message, CreditedFeedback):
                driven[parse_key(event.key).owner].hear(node, event.message)
        for one in driven.values():
            one.save()
            if one.online.book.episodes:
                one.online.book.save(one.path.with_name(f"traces-{one.robot}.npz"))
            node.counters.update({f"learner.{k}": v for k, v in one.learner.counters.items()})
    return 0


def fit(node: Node, one: Driven, limits: object) -> None:
    """Fits a robot's actions to its limits (none came: it goes unscaled, said once)."""
    if isinstance(limits, RobotLimits):
        scale = one.fit(limits)
        node.log.info(
            "actions fit to the robot's limits",
            extra=fields(robot=one.robot, scale=f"{scale:.3g}", max_speed=limits.max_speed,
                         max_turn=limits.max_turn),
        )  # fmt: skip
    elif not one.fitted:
        one.fitted = True
        node.log.warning(
            "the robot said no limits: actions go unscaled (a robot of an older build?)",
            extra=fields(robot=one.robot),
        )


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
            states=len(learner.states),
            episodes=learner.episode,
            resumed_at_step=bookmark.step if bookmark.step is not None else "-",
            feedback_taken=len(bookmark.taken),
        ),
    )
    initial = TraceBook.load(traces) if traces else None
    if initial and not initial.poses:
        node.log.warning(
            "initial traces saved without the robot's position show no way: record them "
            "again (positions are saved now), or run without --traces",
            extra=fields(traces=traces),
        )
    if initial:
        shown = initial.show(learner)
        node.log.info("shown the way by initial traces", extra=fields(robot=robot, traces=shown))
    online = OnlineLearner(learner, bookmark, node.counters, timeout_s)
    node.subscribe("obs", robot)
    node.subscribe("feedback", robot)
    node.subscribe("limits", robot)
    act = node.advertise("action", robot)
    summary = node.advertise("learning", robot)
    ask = node.advertise("help", robot)
    return Driven(robot, path, learner, bookmark, online, act, summary, ask)

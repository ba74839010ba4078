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

from protocol import Action, CreditedFeedback, LearningSummary, Observation, check_id, robot_key
from services.learner import checkpoint
from services.learner.config import add_settings_argument, with_settings
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
    learner, progress = resumed or (Learner(config, args.seed), checkpoint.Progress())
    book = TraceBook()
    with Node("learner", bus) as node:
        node.log.info(
            "learning",
            extra=fields(
                robot=robot,
                checkpoint=path,
                states=len(learner.states),
                episodes=learner.episode,
                resumed_at_step=progress.step if progress.step is not None else "-",
                feedback_taken=len(progress.taken),
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
            if isinstance(event, Input) and isinstance(event.message, Observation):
                obs = event.message
                if obs.episode_step == 0 and learner.s is not None:
                    learner.interrupt()  # missed the end of the last episode
                decision = learner.step(obs)
                progress.step = obs.step
                book.record(obs, decision)
                if decision is None and initial:
                    initial.replay_if_due(learner)
                if decision is not None:
                    act.put(
                        Action(
                            robot=robot,
                            episode=obs.episode,
                            step=obs.step,
                            discrete=decision.discrete,
                            v=decision.v,
                            omega=decision.omega,
                            chooser=decision.chooser,
                        )
                    )
                summary.put(_summary(learner, obs))
            elif isinstance(event, Input) and isinstance(event.message, CreditedFeedback):
                _take(learner, progress, event.message, node)
            if time.monotonic() - last_save >= args.checkpoint_every:
                checkpoint.save(learner, path, progress)
                last_save = time.monotonic()
        for _ in range(MAX_PENDING):  # feedback that arrived before the stop is taken too
            event = node.poll(0)
            if event is None:
                break
            if isinstance(event, Input) and isinstance(event.message, CreditedFeedback):
                _take(learner, progress, event.message, node)
        checkpoint.save(learner, path, progress)
        if book.episodes:
            book.save(path.with_name(f"traces-{robot}.npz"))
        node.counters.update({f"learner.{k}": v for k, v in learner.counters.items()})
    return 0


def _take(
    learner: Learner, progress: checkpoint.Progress, feedback: CreditedFeedback, node: Node
) -> None:
    """Feedback taken once: a copy delivered again (after a restart) is skipped."""
    if not progress.take(feedback.id):
        node.counters["learner.feedback_taken_before"] += 1
        return
    dropped = learner.take(feedback)
    if dropped:
        node.counters["learner.feedback_partly_dropped"] += 1
    if dropped and worth_logging(node.counters["learner.feedback_partly_dropped"]):
        node.log.warning(
            "feedback for steps outside the window dropped",
            extra=fields(
                steps=f"{min(dropped)}..{max(dropped)}",
                of_credits=f"{len(dropped)}/{len(feedback.credits)}",
                teachers=",".join(feedback.teachers),
            ),
        )


def _summary(learner: Learner, obs: Observation) -> LearningSummary:
    """After a terminal step the robot is in no state: state 0 and no Q-values."""
    s = learner.s
    return LearningSummary(
        robot=obs.robot,
        episode=obs.episode,
        step=obs.step,
        state=s if s is not None else 0,
        states=len(learner.states),
        q_values=tuple(float(q) for q in learner.value(s)) if s is not None else (),
        td_error=learner.td_error,
        epsilon=learner.config.epsilon(learner.episode),
        reward=obs.reward,
        episode_return=learner.episode_return,
    )

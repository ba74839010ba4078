"""Support for the stopped-observer fault tests (tests/test_faults.py): a session whose robot
runs as fast as its learner answers (a lockstep simulator), a teacher typing words, a logger,
and an observer stopped with SIGSTOP for a while. What the test's own bus node saw (the
robot's pace, the feedback and when it came, the teacher's actions) and what a logger's event
log holds afterwards."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from statistics import median

from tests.conftest import VOXSHAPE, bus_args
from voxshape.protocol import (
    ACTION_NAMES,
    Action,
    CreditedFeedback,
    Observation,
    Utterance,
    robot_key,
    teacher_key,
)
from voxshape.runtime import Input, Node
from voxshape.services.logger.decoding import Gap, Known, decode_record
from voxshape.services.logger.eventlog import read_events

JSON_LOGS = {**os.environ, "VOXSHAPE_LOG_FORMAT": "json"}
STOP_S = 10.0  # past zenoh's 10 s lease and the 5 s a router waits before closing a transport
WINDOW_S = 0.5
# Words typed during the stop, at these seconds into it: two commands, carried out in order
DURING = ((1.5, "left"), (4.0, "good"), (6.5, "right"), (8.5, "bad"))


@dataclass
class Seen:
    """What the test's bus node saw. Times are wall clock (the simulator stamps each step)."""

    steps: list[tuple[float, int]] = field(default_factory=list)  # (wall_time, step) of obs
    feedback: dict[str, tuple[float, CreditedFeedback]] = field(default_factory=dict)
    utterances: dict[str, Utterance] = field(default_factory=dict)
    teacher_actions: list[str] = field(default_factory=list)  # discrete names, in order
    phases: dict[str, tuple[float, float]] = field(default_factory=dict)  # name -> (from, to)
    stood: int = 0  # steps the robot took without its learner's action (it waited 2 s each)

    def windows(self, phase: str) -> list[float]:
        """The robot's steps per second in each 0.5 s window of a phase, from the steps'
        own times: what the robot did, whatever reached this node late or not at all."""
        start, end = self.phases[phase]
        out, t = [], start
        while t + WINDOW_S <= end:
            inside = [step for at, step in self.steps if t <= at < t + WINDOW_S]
            before = [step for at, step in self.steps if at < t]
            last = max(inside, default=max(before, default=0))
            out.append((last - max(before, default=last)) / WINDOW_S)
            t += WINDOW_S
        return out

    def before(self) -> float:
        """The robot's pace before the stop: the median window."""
        return median(self.windows("before"))

    def during_stop(self, what: list[str]) -> list[CreditedFeedback]:
        """The feedback about words in `what` that arrived while the observer was stopped."""
        start, end = self.phases["stopped"]
        return [
            f for t, f in self.feedback.values() if start <= t <= end and (f.command or "") in what
        ]


def service(spawn, role: str, router: str, session_id: str, node: str, *args: str, **kw):
    kw.setdefault("text", True)
    return spawn([VOXSHAPE, role, *bus_args(router, session_id, node), *args], **kw)


def start_session(spawn, router: str, session_id: str, run: Path) -> dict[str, subprocess.Popen]:
    """The robot in lockstep (it steps as soon as its learner answers), its learner, the
    arbiter, a logger writing under `run`, and a teacher who types (`teach`'s stdin). Their
    logs go to `run`/<name>.log."""
    run.mkdir(parents=True, exist_ok=True)

    def start(role: str, *args: str, **kw) -> subprocess.Popen:
        with (run / f"{role}.log").open("w") as log:
            return service(spawn, role, router, session_id, role, *args, stdout=log,
                           stderr=subprocess.STDOUT, env=JSON_LOGS, **kw)  # fmt: skip

    return {
        "logger": start("logger", "--serve-port", "0", cwd=run),
        "sim": start("sim", "--clock", "lockstep", "--seed", "0"),
        # it never asks: an answer to its question is advice, not a command carried out; and
        # a turn is turned in full: at this pace the heading the teacher saw is seconds of
        # turning ago, and an aimed turn may already be there
        "learner": start("learner", "--seed", "0", "--checkpoint", str(run / "learner.npz"),
                         "--set", "ask.per_robot_minute=0", "--set", "command_aim=0"),
        "arbiter": start("arbiter", cwd=run),
        "teach": start("teach", "--teacher", "ana", "--robot", "r1", "--json", "--linger", "1",
                       stdin=subprocess.PIPE, cwd=run),
    }  # fmt: skip


def watch(node: Node, session_id: str) -> None:
    node.input("obs", robot_key(session_id, "r1", "obs"))
    node.input("action", robot_key(session_id, "r1", "action"))
    node.input("feedback", robot_key(session_id, "r1", "feedback"))
    node.input("utterance", teacher_key(session_id, "ana", "utterance"))


def say(teach: subprocess.Popen, word: str) -> None:
    teach.stdin.write(word + "\n")
    teach.stdin.flush()


def note(node: Node, seen: Seen, until: float) -> None:
    """Takes what comes until `until` (wall clock)."""
    while time.time() < until:
        event = node.poll(0.02)
        if not isinstance(event, Input):
            continue
        match event.message:
            case Observation() as obs:
                seen.steps.append((obs.wall_time, obs.step))
            case Action(chooser="teacher", discrete=int() as action):
                seen.teacher_actions.append(ACTION_NAMES[action])
            case CreditedFeedback() as feedback:
                seen.feedback[feedback.id] = (time.time(), feedback)
            case Utterance() as utterance:
                seen.utterances[utterance.id] = utterance


def phase(node: Node, seen: Seen, name: str, seconds: float, words=()) -> None:
    """A phase of `seconds`, the teacher saying `words` ((second into it, word)) meanwhile."""
    start = time.time()
    for at, word, teach in words:
        note(node, seen, start + at)
        say(teach, word)
    note(node, seen, start + seconds)
    seen.phases[name] = (start, time.time())


def stop_for(node: Node, seen: Seen, observer: subprocess.Popen, teach: subprocess.Popen) -> None:
    """4 s of pace before, the observer stopped for STOP_S while the teacher types DURING,
    then continued, and 4 s after."""
    say(teach, "good")  # its word, before: every output on the way declared and warm
    note(node, seen, time.time() + 4.0)
    phase(node, seen, "before", 4.0)
    observer.send_signal(signal.SIGSTOP)
    phase(node, seen, "stopped", STOP_S, [(at, word, teach) for at, word in DURING])
    observer.send_signal(signal.SIGCONT)
    phase(node, seen, "continued", 4.0)


def in_order(actions: list[str]) -> list[str]:
    """The teacher's actions as runs: ["left", "left", "right"] -> ["left", "right"]."""
    return [a for i, a in enumerate(actions) if i == 0 or actions[i - 1] != a]


@dataclass
class Logged:
    """What a logger's event log holds of the session."""

    utterances: set[str]
    feedback: set[str]
    obs_steps: set[int]
    missed: Counter[str]  # messages marked as gaps, by topic

    @property
    def obs_unaccounted(self) -> int:
        """Steps between the first and the last logged that are neither logged nor in a gap."""
        span = max(self.obs_steps) - min(self.obs_steps) + 1
        return span - len(self.obs_steps) - self.missed["obs"]


def logged(events: Path) -> Logged:
    out = Logged(set(), set(), set(), Counter())
    for record in read_events(events).records:
        match decode_record(record):
            case Known(message=Utterance() as u):
                out.utterances.add(u.id)
            case Known(message=CreditedFeedback() as f):
                out.feedback.add(f.id)
            case Known(message=Observation() as obs) if obs.robot == "r1":
                out.obs_steps.add(obs.step)
            case Gap(missed=missed):
                out.missed[record.key.rsplit("/", 1)[-1]] += missed
    return out

"""The whole stack over zenoh, every service its own process, taught by `voxshape sim-teacher`
through the mock speech engine: two teachers merge on one robot; two robots of one session
are taught apart. (That it learns task 1 to convergence is the demo's test, tests/test_demo.py.)"""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest

from tests.conftest import VOXSHAPE, bus_args, wait_present
from voxshape.protocol import CreditedFeedback, TeachingStats, robot_key
from voxshape.runtime import Input, Node

RTF = 20  # paced: the arbiter credits by wall-clock display time (see voxshape/lab/demo.py); the
# simulated teachers' delays are robot seconds, and the arbiter is told so (--robot-time)
SEED = 5


class Stack:
    def __init__(self, spawn: Callable, router: str, session_id: str, cwd) -> None:
        self.spawn, self.router, self.session_id, self.cwd = spawn, router, session_id, cwd

    def start(self, node: str, *argv: str) -> None:
        command, *rest = argv
        self.spawn(
            [VOXSHAPE, command, *bus_args(self.router, self.session_id, node), *rest],
            cwd=self.cwd,
        )


def start_services(stack: Stack, robots: tuple[str, ...], teachers: dict[str, str]) -> None:
    """Arbiter, mock speech, a learner per robot, the simulated teachers (teacher -> robot);
    the simulator last, once everyone is present."""
    robot_time = [flag for teacher in teachers for flag in ("--robot-time", teacher)]
    stack.start("arbiter", "arbiter", *robot_time)
    stack.start("speech", "speech", "--engine", "mock", "--seed", "1")
    for robot in robots:
        stack.start(f"learner-{robot}", "learner", "--robot", robot, "--seed", str(SEED))
    for i, (teacher, robot) in enumerate(teachers.items()):
        stack.start(
            teacher, "sim-teacher", "--teacher", teacher, "--robot", robot, "--seed", str(i + 1)
        )


def start_sim(stack: Stack, robots: tuple[str, ...]) -> None:
    robot_flags = [flag for robot in robots for flag in ("--robot", robot)]
    stack.start("sim", "sim", "--rtf", str(RTF), "--seed", str(SEED), *robot_flags)


@pytest.fixture
def stack(spawn, router, session_id, tmp_path) -> Stack:
    return Stack(spawn, router, session_id, tmp_path)


def test_two_teachers_on_one_robot_are_merged(stack, client_config, session_id):
    with Node("test", client_config("observer")) as node:
        node.watch_presence()
        node.input("teaching", robot_key(session_id, "r1", "teaching"))
        node.input("feedback", robot_key(session_id, "r1", "feedback"))
        start_services(stack, ("r1",), {"ana": "r1", "bob": "r1"})
        wait_present(node, {"arbiter", "speech", "learner-r1", "ana", "bob"})
        start_sim(stack, ("r1",))
        understood: dict[str, int] = {}
        credited: set[str] = set()
        widths: list[int] = []
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and not (
            min(understood.get("ana", 0), understood.get("bob", 0)) > 0
            and {"ana", "bob"} <= credited
        ):
            event = node.poll(0.2)
            if isinstance(event, Input) and isinstance(event.message, TeachingStats):
                understood.update({t.teacher: t.understood for t in event.message.teachers})
            elif isinstance(event, Input) and isinstance(event.message, CreditedFeedback):
                credited.update(event.message.teachers)
                steps = [c.step for c in event.message.credits]
                widths.append(max(steps) - min(steps) + 1)
        assert understood.get("ana", 0) > 0 and understood.get("bob", 0) > 0, understood
        assert {"ana", "bob"} <= credited, credited
        # a 0.6 robot-second window covers about 6 steps at 20x too (in wall seconds: ~120)
        assert max(widths) <= 20, widths


def test_two_robots_in_one_session_are_taught_apart(stack, client_config, session_id):
    with Node("test", client_config("observer")) as node:
        node.watch_presence()
        for robot in ("r1", "r2"):
            node.input("feedback", robot_key(session_id, robot, "feedback"))
            node.input("teaching", robot_key(session_id, robot, "teaching"))
        start_services(stack, ("r1", "r2"), {"ana": "r1", "bob": "r2"})
        wait_present(node, {"arbiter", "speech", "learner-r1", "learner-r2", "ana", "bob"})
        start_sim(stack, ("r1", "r2"))
        teachers_of: dict[str, set[str]] = {"r1": set(), "r2": set()}
        stats_of: dict[str, set[str]] = {"r1": set(), "r2": set()}
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and not all(
            len(teachers_of[r]) and len(stats_of[r]) for r in teachers_of
        ):
            event = node.poll(0.2)
            if not isinstance(event, Input):
                continue
            robot = event.key.split("/")[-2]
            match event.message:
                case CreditedFeedback() as fb:
                    assert fb.robot == robot
                    teachers_of[robot].update(fb.teachers)
                case TeachingStats() as stats:
                    stats_of[robot].update(t.teacher for t in stats.teachers if t.utterances)
        assert teachers_of == {"r1": {"ana"}, "r2": {"bob"}}, teachers_of
        assert stats_of == {"r1": {"ana"}, "r2": {"bob"}}, stats_of

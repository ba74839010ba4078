"""A ROS 2 robot learns task 1 through `voxshape ros2`, taught by the simulated person, and
converges: the robot (tests/ros2_robot.py, rmw_zenoh as its design document says, written
against rosbags) plays the simulator's world behind its own router, at 20x real time, as
the bridge does; a learner, an arbiter, the mock speech service and the simulated teacher
run as `voxshape demo` runs them (LocalSession). Every cmd_vel the robot received carried a
valid attachment."""

from __future__ import annotations

import json
import time

import pytest

from protocol import EpisodeEvent, TeachingStats, robot_key
from services.demo import ConvergenceWatch
from services.launcher import LocalSession, ServiceDied
from services.runtime import Input
from services.topology import ServiceSpec
from tests.conftest import ROOT, free_port

RTF = 20
MAX_EPISODES = 100
TIMEOUT_S = 540  # measured: see docs/robot.md#how-it-is-tested


def specs(session: str, router: str, robot_router: str, log: str) -> list[ServiceSpec]:
    bus = {
        "VOXSHAPE_SESSION": session,
        "VOXSHAPE_MODE": "client",
        "VOXSHAPE_CONNECT": router,
        "VOXSHAPE_TASK": "1",
        "VOXSHAPE_LOG_LEVEL": "WARNING",
    }

    def spec(name: str, command: list[str], after: tuple[str, ...] = ("router",), **env: str):
        return ServiceSpec(name, tuple(command), {**bus, "VOXSHAPE_NODE": name, **env}, after, ())

    robot = ServiceSpec(
        "robot",
        ("python", str(ROOT / "tests" / "ros2_robot.py"), "--listen", robot_router,
         "--rtf", str(RTF), "--log", log),
        {}, (), (), on_bus=False,
    )  # fmt: skip
    return [
        ServiceSpec(
            "router",
            ("voxshape", "router"),
            {
                **bus,
                "VOXSHAPE_NODE": "router",
                "VOXSHAPE_LISTEN": router,
                "VOXSHAPE_CONNECT": "",
                "VOXSHAPE_MODE": "router",
            },
            (),
            (),
            on_bus=True,
        ),
        robot,
        spec("learner", ["voxshape", "learner", "--fresh", "--seed", "1"]),
        spec("arbiter", ["voxshape", "arbiter"], VOXSHAPE_ROBOT_TIME="simteacher"),
        spec("speech", ["voxshape", "speech", "--engine", "mock", "--seed", "1"]),
        spec(
            "simteacher",
            ["voxshape", "sim-teacher", "--seed", "1", "--teacher-profile", "person"],
            ("router", "speech"),
            VOXSHAPE_TEACHER="simteacher",
            VOXSHAPE_ROBOT="r1",
        ),
        spec(
            "ros2",
            [
                "voxshape",
                "ros2",
                "--connect",
                robot_router,
                "--goal",
                "5,5",
                "--rtf",
                str(RTF),
                "--max-speed",
                "0.7",
                "--max-turn",
                "1.75",
                "--radius",
                "0.25",
            ],
            ("router", "learner", "simteacher"),
        ),
    ]


@pytest.mark.timeout(TIMEOUT_S + 60)
def test_a_ros2_robot_learns_task_1_through_the_bridge_and_converges(
    tmp_path, session_id, monkeypatch
):
    router = f"tcp/127.0.0.1:{free_port()}"
    robot_router = f"tcp/127.0.0.1:{free_port()}"
    log = tmp_path / "cmd_vel.jsonl"
    monkeypatch.setenv("VOXSHAPE_SESSION", session_id)  # the launcher's own node's
    monkeypatch.chdir(tmp_path)  # the learner writes under ./runs
    session = LocalSession(specs(session_id, router, str(robot_router), str(log)), router, 60.0)
    progress = ConvergenceWatch("r1", MAX_EPISODES)
    session.input("episode", robot_key(session_id, "r1", "episode"))
    session.input("teaching", robot_key(session_id, "r1", "teaching"))
    t0 = time.monotonic()
    try:
        session.start()
        assert session.bus is not None
        for event in session.bus.events(tick=1.0):
            if isinstance(event, Input) and isinstance(event.message, EpisodeEvent):
                progress.on_episode(event.message, time.monotonic())
            elif isinstance(event, Input) and isinstance(event.message, TeachingStats):
                progress.on_teaching(event.message)
            session.check_children()
            if progress.done or time.monotonic() - t0 > TIMEOUT_S:
                break
    except ServiceDied as e:
        pytest.fail(str(e))
    finally:
        session.stop()
    minutes = (time.monotonic() - t0) / 60
    lines = [line for line in progress.due_lines(time.monotonic(), flush=True)]
    print("\n".join(lines))
    c = progress.convergence
    print(
        f"{len(progress.episodes)} episodes, converged: {c.converged}, {minutes:.1f} wall minutes"
    )
    assert c.converged, "\n".join(lines)
    assert any(e.interventions for e in progress.episodes), "the teacher was never heard"
    cmds = [json.loads(line) for line in log.read_text().splitlines()]
    assert len(cmds) > 1000 and all(c["attachment"] == "ok" for c in cmds)

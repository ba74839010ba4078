"""`voxshape ros2` on real buses: a ROS 2 robot (tests/ros2_robot.py, written against
rmw_zenoh's design document and rosbags, not our bridge) behind its own zenoh router, the
bridge, and a session's router. The robot checks every cmd_vel's attachment; the faults the
bridge's safety exists for are played for real: a learner killed, the robot's driver gone
silent, the session's router gone, the bridge stopped or killed, the robot backing into a
wall or seeing itself inside its bump radius; and a real learner's actions fit the robot's
limits."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field, replace

import pytest
import zenoh

from tests.conftest import ROOT, VOXSHAPE, bus_args, collect, free_port
from voxshape.launcher import router_command
from voxshape.protocol import Action, EpisodeEvent, Observation, robot_key
from voxshape.runtime import Node
from voxshape.runtime.config import wait_for_loopback_port

ROBOT_SCRIPT = str(ROOT / "tests" / "ros2_robot.py")


@dataclass
class RobotProcess:
    """The robot's process and what it printed: one JSON object per cmd_vel it received."""

    proc: subprocess.Popen
    endpoint: str
    lines: list[dict] = field(default_factory=list)

    def read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(json.loads(line))

    def cmds(self) -> list[dict]:
        return [line for line in self.lines if "cmd" in line]

    def wait_for(self, what, timeout: float = 15.0) -> dict:
        deadline = time.monotonic() + timeout
        seen = 0
        while time.monotonic() < deadline:
            for line in self.cmds()[seen:]:
                if what(line):
                    return line
                seen += 1
            time.sleep(0.02)
        raise AssertionError(f"the robot received no such cmd_vel; last: {self.cmds()[-5:]}")

    def say(self, text: str) -> None:
        self.proc.stdin.write(text + "\n")
        self.proc.stdin.flush()


def start_robot(spawn, *extra: str) -> RobotProcess:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    proc = spawn(
        [sys.executable, ROBOT_SCRIPT, "--listen", endpoint, *extra],
        stdin=subprocess.PIPE,
        text=True,
    )
    robot = RobotProcess(proc, endpoint)
    threading.Thread(target=robot.read, daemon=True).start()
    wait_for_loopback_port(port)
    return robot


def start_bridge(spawn, router, session_id, robot: RobotProcess, *extra: str, log=None):
    argv = [VOXSHAPE, "ros2", *bus_args(router, session_id, "ros2")]
    argv = [a.replace("--connect", "--bus").replace("--mode", "--bus-mode") for a in argv]
    env = {**os.environ, "VOXSHAPE_LOG_FORMAT": "json"}
    return spawn(
        [*argv, "--connect", robot.endpoint, "--goal", "5,5", "--max-speed", "0.7", *extra],
        stdout=subprocess.DEVNULL,
        stderr=log if log is not None else subprocess.PIPE,
        text=True,
        env=env,
    )


@pytest.fixture
def learner_node(client_config, session_id):
    """The test as the robot's learner: observations and episodes in, actions out."""
    with Node("test", client_config("learner-test")) as node:
        node.input("obs", robot_key(session_id, "r1", "obs"))
        node.input("episode", robot_key(session_id, "r1", "episode"))
        yield node, node.output("action", robot_key(session_id, "r1", "action"))


def action(obs: Observation, v: float = 0.3) -> Action:
    return Action(
        robot="r1", episode=obs.episode, step=obs.step, discrete=1, v=v, omega=0.0, chooser="policy"
    )


def drive_until(node, out, until, timeout: float = 10.0, v: float = 0.3) -> None:
    """Answers every observation with an action until `until()`."""
    deadline = time.monotonic() + timeout
    while not until() and time.monotonic() < deadline:
        (obs,) = collect(node, 1, Observation, timeout=5.0)
        if obs.outcome == "running":
            out.put(action(obs, v))
    assert until(), "not within the time"


def stop_gap(robot: RobotProcess, after: float) -> float:
    """Seconds between the last non-zero cmd_vel the robot received and the zero after it."""
    cmds = robot.cmds()
    zero = next(c for c in cmds if c["t"] > after and c["cmd"] == [0.0, 0.0])
    moving = [c for c in cmds if c["t"] < zero["t"] and c["cmd"] != [0.0, 0.0]]
    return zero["t"] - moving[-1]["t"]


def test_a_ros2_robot_on_rmw_zenoh_is_a_robot_of_the_session(
    spawn, router, session_id, learner_node, tmp_path
):
    node, out = learner_node
    robot = start_robot(spawn)
    with (tmp_path / "bridge.log").open("w") as log:
        bridge = start_bridge(spawn, router, session_id, robot, log=log)
    # the episode's start and its first observation, in either order (a key each)
    got = collect(node, 2, (EpisodeEvent, Observation), timeout=20.0)
    start = next(m for m in got if isinstance(m, EpisodeEvent))
    first = next(m for m in got if isinstance(m, Observation))
    assert start.kind == "start" and (first.x, first.y, first.episode_step) == (1.0, 1.0, 0)
    assert len(first.laser) == 180 and len(first.sonar) == 8
    assert first.goal_distance == pytest.approx(4 * 2**0.5)
    out.put(action(first, v=0.3))
    cmd = robot.wait_for(lambda c: c["cmd"][0] > 0)
    assert cmd == {**cmd, "cmd": [0.3, 0.0], "attachment": "ok"}
    drive_until(node, out, lambda: len(robot.cmds()) >= 10)
    later = collect(node, 3, Observation)[-1]
    assert later.x > 1.05  # it moved, and its odometry says so
    # The ROS graph sees the bridge: its node, two subscriptions and a publisher.
    with zenoh.open(
        zenoh.Config.from_json5(
            json.dumps(
                {
                    "mode": "client",
                    "connect": {"endpoints": [robot.endpoint]},
                    "scouting": {"multicast": {"enabled": False}},
                }
            )
        )
    ) as ros:
        tokens = [str(r.ok.key_expr) for r in ros.liveliness().get("@ros2_lv/0/**")]
    mine = [t for t in tokens if "/voxshape_r1" in t]
    assert sorted(t.split("/")[5] for t in mine) == ["MP", "MS", "MS", "NN"], tokens
    bridge.send_signal(signal.SIGINT)
    assert bridge.wait(timeout=15) == 0
    assert stop_gap(robot, cmd["t"]) < 0.5  # stopped on exit
    assert all(c["attachment"] == "ok" for c in robot.cmds()), robot.cmds()
    left = [json.loads(x) for x in (tmp_path / "bridge.log").read_text().splitlines()]
    (bye,) = [x for x in left if x.get("message") == "left the bus"]
    assert (bye["publishes"], bye["subscribes"]) == (
        "robot/r1/episode robot/r1/limits robot/r1/obs",
        "robot/r1/action teacher/*/placed",
    )  # exactly its row of voxshape/protocol/dataflow.py


def test_killing_the_learner_stops_the_robot_within_half_a_second(
    spawn, router, session_id, tmp_path
):
    robot = start_robot(spawn)
    start_bridge(spawn, router, session_id, robot)
    learner = spawn(
        [VOXSHAPE, "learner", *bus_args(router, session_id, "learner"), "--fresh", "--seed", "1",
         "--checkpoint", str(tmp_path / "learner.npz")],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    robot.wait_for(lambda c: c["cmd"] != [0.0, 0.0], timeout=30)
    time.sleep(1.0)  # it drives a while
    killed = time.monotonic()
    learner.send_signal(signal.SIGKILL)
    robot.wait_for(lambda c: c["t"] > killed and c["cmd"] == [0.0, 0.0], timeout=5)
    gap = stop_gap(robot, killed - 0.5)
    print(f"robot stopped {gap:.3f} s after its last command from the learner")
    assert gap <= 0.5


class Insistent:
    """A learner that will not stop: the last observation's action every 50 ms, whether new
    observations come or not (so only the bridge's own checks can stop the robot)."""

    def __init__(self, out, obs: Observation) -> None:
        self.out, self.obs, self.stopped = out, obs, threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self) -> None:
        while not self.stopped.wait(0.05):
            try:
                self.out.put(action(self.obs, 0.3))
            except Exception:  # the session closed under it
                return

    def stop(self) -> None:
        self.stopped.set()
        self.thread.join(timeout=2)


def test_a_silent_robot_stops_it(spawn, router, session_id, learner_node):
    node, out = learner_node
    robot = start_robot(spawn)
    start_bridge(spawn, router, session_id, robot)
    collect(node, 1, EpisodeEvent, timeout=20.0)
    (obs,) = collect(node, 1, Observation)
    insistent = Insistent(out, obs)
    try:
        robot.wait_for(lambda c: c["cmd"][0] > 0)
        time.sleep(0.5)
        muted = time.monotonic()
        robot.say("mute")  # its driver died: no scan, no odometry
        robot.wait_for(lambda c: c["t"] > muted and c["cmd"] == [0.0, 0.0], timeout=5)
    finally:
        insistent.stop()
    assert stop_gap(robot, muted) <= 0.7  # data_timeout 0.5 s, then the next action


def test_the_session_s_router_lost_stops_it(spawn, session_id, client_config):
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    argv = router_command("--session", session_id, "--node", "router2", "--listen", endpoint)
    own = spawn(argv)
    wait_for_loopback_port(port)
    robot = start_robot(spawn)
    start_bridge(spawn, endpoint, session_id, robot)
    with Node("test", replace(client_config("learner-test"), connect=(endpoint,))) as node:
        node.input("obs", robot_key(session_id, "r1", "obs"))
        out = node.output("action", robot_key(session_id, "r1", "action"))
        (obs,) = collect(node, 1, Observation, timeout=20)
        insistent = Insistent(out, obs)
        try:
            robot.wait_for(lambda c: c["cmd"][0] > 0)
            time.sleep(0.5)
            lost = time.monotonic()
            own.send_signal(signal.SIGKILL)
            zero = robot.wait_for(lambda c: c["t"] > lost and c["cmd"] == [0.0, 0.0], timeout=5)
        finally:
            insistent.stop()
    # At once: sooner than the last command would lapse (0.4 s), which would stop it too.
    print(f"robot stopped {zero['t'] - lost:.3f} s after the session's router died")
    assert zero["t"] - lost < 0.3


@pytest.mark.parametrize(
    ("robot_flags", "bridge_flags"),
    [
        (("--cmd", "twist_stamped", "--attachment", "77"), ("--cmd", "twist_stamped")),
        (
            ("--mode", "ros2dds", "--namespace", "/bot1"),
            ("--mode", "ros2dds", "--namespace", "/bot1"),
        ),
    ],
    ids=["jazzy-before-0.2.4-twist-stamped", "dds-robot-via-zenoh-bridge-ros2dds"],
)
def test_older_rmw_zenoh_twist_stamped_and_dds_robots(
    spawn, router, session_id, learner_node, robot_flags, bridge_flags
):
    node, out = learner_node
    robot = start_robot(spawn, *robot_flags)
    start_bridge(spawn, router, session_id, robot, *bridge_flags)
    collect(node, 1, EpisodeEvent, timeout=20.0)
    drive_until(node, out, lambda: sum(c["cmd"][0] > 0 for c in robot.cmds()) >= 5)
    moving = [c for c in robot.cmds() if c["cmd"][0] > 0]
    # The 77-byte format is taken from the robot's own samples (the first cmd_vel may go
    # out before one came, in the 33-byte default).
    assert all(c["attachment"] == "ok" for c in moving[1:]), moving


def test_a_waiting_robot_is_placed_by_a_teacher(spawn, router, session_id, learner_node, tmp_path):
    quick = tmp_path / "quick.toml"
    quick.write_text(
        (ROOT / "voxshape" / "world" / "maps" / "task1.toml")
        .read_text()
        .replace("timeout = 300.0", "timeout = 3.0")
    )
    node, out = learner_node
    robot = start_robot(spawn, "--task", str(quick))
    start_bridge(spawn, router, session_id, robot, "--reset", "wait", "--task", str(quick))
    collect(node, 1, EpisodeEvent, timeout=20.0)
    ended = []

    def over() -> bool:
        return bool(ended)

    deadline = time.monotonic() + 15
    while not ended and time.monotonic() < deadline:
        event = collect(node, 1, (Observation, EpisodeEvent))[0]
        if isinstance(event, Observation) and event.outcome == "running":
            out.put(action(event, 0.4))
        elif isinstance(event, EpisodeEvent) and event.kind != "start":
            ended.append(event)
    assert ended and ended[0].kind == "timeout"
    robot.say("place")  # carried back: its odometry did not see it
    time.sleep(0.5)
    told = subprocess.run(
        [VOXSHAPE, "placed", *bus_args(router, session_id, "placer"), "--robot", "r1",
         "--teacher", "ana"],
        capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    assert told.returncode == 0 and "robot r1 is at its start" in told.stdout, told.stderr
    # The ended episode's last observations may still be on their way (zenoh orders messages
    # per key only, and episodes and observations have a key each): skipped, if of that one.
    start, first, ended_obs = None, None, []
    for _ in range(50):
        if start is not None and first is not None:
            break
        (event,) = collect(node, 1, (EpisodeEvent, Observation), timeout=10)
        if isinstance(event, EpisodeEvent):
            start = start or event
        elif event.episode == 0:
            ended_obs.append(event)
        else:
            first = first or event
    assert start is not None and first is not None, (start, first)
    assert {obs.outcome for obs in ended_obs} <= {"running", "timeout"}, ended_obs
    assert start.kind == "start" and start.episode == 1
    assert (first.x, first.y) == pytest.approx((1.0, 1.0), abs=0.02)  # re-anchored


def bump_run(spawn, router, session_id, learner_node, *bridge_flags: str):
    """The robot backs (as told "back") until its episode ends: the robot's lines, the end."""
    node, out = learner_node
    robot = start_robot(spawn)
    start_bridge(spawn, router, session_id, robot, *bridge_flags)
    collect(node, 1, EpisodeEvent, timeout=20.0)
    deadline, end = time.monotonic() + 20, None
    while end is None and time.monotonic() < deadline:
        (event,) = collect(node, 1, (Observation, EpisodeEvent), timeout=5.0)
        if isinstance(event, EpisodeEvent) and event.kind != "start":
            end = event
        elif isinstance(event, Observation) and event.outcome == "running":
            out.put(action(event, v=-0.2))
    assert end is not None, "the episode never ended"
    time.sleep(0.5)  # the stop reaches the robot
    return robot, end


@pytest.mark.parametrize(
    ("radius", "seen_by"), [("0.2", "odometry"), ("0.3", "scan")], ids=["odometry", "scan"]
)
def test_a_robot_backing_into_a_wall_bumps_and_is_stopped(
    spawn, router, session_id, learner_node, radius, seen_by
):
    """The robot (a 0.2 m disk) backs towards the wall behind its start: with a bump radius of
    its own size no scan reading ever gets nearer, and its odometry standing still tells; with
    a larger one the scan tells, before it touches. Either way the episode ends as a collision
    and a zero command goes out within a second of the contact."""
    robot, end = bump_run(spawn, router, session_id, learner_node, "--radius", radius)
    assert end.kind == "collision"
    contact = next((line["t"] for line in robot.lines if line.get("contact")), None)
    backing = [c["t"] for c in robot.cmds() if c["cmd"][0] < 0]
    stop = next(c["t"] for c in robot.cmds() if c["t"] > backing[-1] and c["cmd"] == [0.0, 0.0])
    in_contact = 0.0 if contact is None or contact > stop else stop - contact
    print(f"bump seen by the {seen_by}: in contact {in_contact:.2f} s before the stop")
    assert in_contact <= 1.0
    if seen_by == "scan":
        assert contact is None or contact >= stop  # stopped before it touched


def test_a_robot_that_sees_itself_inside_its_radius_is_refused(spawn, router, session_id):
    robot = start_robot(spawn, "--mast", "0.15")  # its lidar sees a mast 0.15 m behind
    bridge = start_bridge(spawn, router, session_id, robot, "--radius", "0.2")
    _, err = bridge.communicate(timeout=30)
    assert bridge.returncode == 2, err
    assert "not starting: the scan reads 0.15 m at +180 deg" in err or "at -180 deg" in err, err
    assert "--radius below that reading" in err
    assert not [c for c in robot.cmds() if c["cmd"] != [0.0, 0.0]]  # it never moved


def test_a_robot_whose_bridge_is_killed_stops_by_itself(spawn, router, session_id, learner_node):
    """SIGKILL: the bridge cannot say stop; the robot's own cmd_vel timeout does (0.5 s)."""
    node, out = learner_node
    robot = start_robot(spawn)
    bridge = start_bridge(spawn, router, session_id, robot)
    collect(node, 1, EpisodeEvent, timeout=20.0)
    drive_until(node, out, lambda: sum(c["cmd"][0] > 0 for c in robot.cmds()) >= 5)
    bridge.send_signal(signal.SIGKILL)
    killed = time.monotonic()
    bridge.wait(10)
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline and not any("timeout" in line for line in robot.lines):
        time.sleep(0.05)
    (stopped,) = [line for line in robot.lines if "timeout" in line]
    last = max(c["t"] for c in robot.cmds())
    print(f"the robot stopped itself {stopped['t'] - last:.2f} s after its last cmd_vel")
    assert stopped["timeout"][0] > 0 and last <= killed + 0.1
    assert stopped["t"] - last <= 1.0  # its 0.5 s, a period of its loop, a loaded machine


def test_a_real_learner_s_actions_fit_the_robot_s_limits(spawn, router, session_id, tmp_path):
    """At the bridge's default limits (0.25 m/s, 1.5 rad/s) the learner's forward 0.5 m/s
    and arcs would all be clipped: the bridge says the limits, the learner scales to fit."""
    robot = start_robot(spawn)
    with (tmp_path / "bridge.log").open("w") as log:
        bridge = start_bridge(spawn, router, session_id, robot, "--max-speed", "0.25", log=log)
    spawn(
        [VOXSHAPE, "learner", *bus_args(router, session_id, "learner"), "--fresh", "--seed", "1",
         "--checkpoint", str(tmp_path / "learner.npz")],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    deadline = time.monotonic() + 60
    while len([c for c in robot.cmds() if c["cmd"] != [0.0, 0.0]]) < 30:
        assert time.monotonic() < deadline, "the learner did not drive it"
        time.sleep(0.1)
    bridge.send_signal(signal.SIGINT)
    assert bridge.wait(timeout=15) == 0
    moving = [c["cmd"] for c in robot.cmds() if c["cmd"] != [0.0, 0.0]]
    (bye,) = [
        json.loads(x)
        for x in (tmp_path / "bridge.log").read_text().splitlines()
        if '"stopped the robot"' in x
    ]
    print(f"{len(moving)} commands, fastest {max(abs(v) for v, _ in moving):.3f} m/s")
    assert bye.get("clipped", 0) == 0 and bye["actions"] >= 5, bye  # (the rest: homing)
    assert max(abs(v) for v, _ in moving) <= 0.25 + 1e-9
    # the learner's forward, 0.5 m/s scaled to fit (homing drives at 0.2 m/s at most)
    assert max(abs(v) for v, _ in moving) == pytest.approx(0.25)

"""`voxshape sim` on a real bus: lockstep and paced clocks, bad actions, several robots and
several simulator processes in one session; `voxshape map` and benchmarks/sim.py."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time

import matplotlib.image
import pytest

from tests.conftest import ROOT, VOXSHAPE, bus_args, collect, quiet
from voxshape.protocol import Action, EpisodeEvent, Observation, robot_key
from voxshape.runtime import Input, Node


def start_sim(spawn, router, session_id, *extra, node="sim"):
    return spawn(
        [VOXSHAPE, "sim", *bus_args(router, session_id, node), "--seed", "0", *extra], text=True
    )


def start_lockstep(spawn, router, session_id, *extra):
    """A lockstep simulator that waits (up to 30 s) for the test's actions."""
    return start_sim(
        spawn, router, session_id, "--clock", "lockstep", "--action-timeout", "30", *extra
    )


def act(
    step: int, v: float | None = 0.5, omega: float | None = 0.0, robot: str = "r1", episode: int = 0
) -> Action:
    return Action(
        robot=robot, episode=episode, step=step, discrete=None, v=v, omega=omega, chooser="policy"
    )


def stop(proc: subprocess.Popen) -> str:
    proc.terminate()
    _, err = proc.communicate(timeout=15)
    return err


@pytest.fixture
def policy(client_config, session_id):
    with Node("test", client_config("policy")) as node:
        node.input("obs", robot_key(session_id, "*", "obs"))
        node.input("episode", robot_key(session_id, "*", "episode"))
        node.watch_presence(node="sim")
        yield node


def wait_for_sim(node: Node, who: str = "sim") -> None:
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        event = node.poll(0.1)
        if getattr(event, "node", None) == who and getattr(event, "alive", False):
            time.sleep(0.3)  # its subscriptions travel with its presence
            return
    pytest.fail(f"{who} never appeared")


def test_lockstep_steps_only_on_the_action_for_the_current_step(spawn, router, session_id, policy):
    sim = start_lockstep(spawn, router, session_id, "--task", "1")
    wait_for_sim(policy)
    out = policy.output("action", robot_key(session_id, "r1", "action"))
    (start,) = collect(policy, 1, Observation)
    assert (start.step, start.episode, start.episode_step) == (0, 0, 0)
    assert not [m for m in quiet(policy, 0.5) if isinstance(m, Observation)]  # waits for us
    out.put(act(0))
    (first,) = collect(policy, 1, Observation)
    assert first.step == 1 and first.outcome == "running"

    out.put(act(0))  # late: answers step 0, the robot is at step 1
    out.put(act(1, robot="r2"))  # on r1's key, says r2
    out.put(
        Action(robot="r1", episode=0, step=1, discrete=2, v=None, omega=None, chooser="teacher")
    )  # no velocities
    assert not [m for m in quiet(policy, 0.5) if isinstance(m, Observation)]

    out.put(act(1, v=3.0))  # beyond the Pioneer's 0.7 m/s: clipped
    (second,) = collect(policy, 1, Observation)
    assert second.step == 2 and second.v == 0.7
    assert second.x - first.x == pytest.approx(0.07 * math.cos(first.theta), abs=1e-9)
    err = stop(sim)
    for reason in ("late", "robot_mismatch", "no_velocity"):
        assert f"reason={reason}" in err, err
    assert "action clipped to the robot's limits" in err


def test_lockstep_wait_is_bounded_then_the_robot_stops(spawn, router, session_id, policy):
    sim = start_sim(spawn, router, session_id, "--clock", "lockstep", "--action-timeout", "0.3")
    wait_for_sim(policy)
    observations = collect(policy, 3, Observation)
    assert [o.step for o in observations] == list(
        range(observations[0].step, observations[0].step + 3)
    )
    assert len({(o.x, o.y, o.theta) for o in observations}) == 1  # stopped: nobody answers
    err = stop(sim)
    assert "no action within the wait: robot stopped for this step" in err


def test_paced_clock_follows_the_real_time_factor(spawn, router, session_id, policy):
    sim = start_sim(spawn, router, session_id, "--clock", "paced", "--rtf", "5")
    wait_for_sim(policy)
    observations = collect(policy, 26, Observation)[1:]
    wall = observations[-1].wall_time - observations[0].wall_time  # the simulator's clock
    sim_seconds = observations[-1].sim_time - observations[0].sim_time
    print(
        f"paced at rtf 5: {24 / wall:.1f} observations/s, real-time factor "
        f"{sim_seconds / wall:.2f} (expected 50 and 5)"
    )
    assert sim_seconds == pytest.approx(2.4, abs=1e-6)
    # never ahead of the real-time factor; behind it only as far as a loaded machine holds it
    assert 1.0 < sim_seconds / wall < 5.5
    stop(sim)


def test_two_robots_in_one_world_each_on_its_own_keys(spawn, router, session_id, policy):
    sim = start_lockstep(
        spawn,
        router,
        session_id,
        "--robot",
        "a",
        "--robot",
        "b",
        "--task",
        "4",
    )
    wait_for_sim(policy)
    starts = collect(policy, 2, Observation)
    print("STARTS", [(o.robot, o.step, o.id) for o in starts])
    assert {(o.robot, o.step) for o in starts} == {("a", 0), ("b", 0)}
    policy.output("a", robot_key(session_id, "a", "action")).put(act(0, robot="a"))
    policy.output("b", robot_key(session_id, "b", "action")).put(act(0, robot="b", v=0.0))
    observations = collect(policy, 2, Observation)
    print("AFTER", [(o.robot, o.step, o.v) for o in observations])
    print(stop(sim))
    by_robot = {o.robot: o for o in observations}
    assert set(by_robot) == {"a", "b"} and by_robot["a"].v == 0.5 and by_robot["b"].v == 0.0
    stop(sim)


def test_two_simulators_in_one_session(spawn, router, session_id, client_config):
    with Node("test", client_config("watcher")) as node:
        node.input("episode", robot_key(session_id, "*", "episode"))
        node.input("obs", robot_key(session_id, "*", "obs"))
        node.watch_presence()
        sims = [
            start_sim(
                spawn,
                router,
                session_id,
                "--robot",
                robot,
                "--task",
                task,
                "--rtf",
                "4",
                node=f"sim-{robot}",
            )
            for robot, task in (("left", "1"), ("right", "2"))
        ]
        seen: dict[str, set] = {"left": set(), "right": set()}
        deadline = time.monotonic() + 15
        while min(len(v) for v in seen.values()) < 5 and time.monotonic() < deadline:
            event = node.poll(0.1)
            if isinstance(event, Input) and isinstance(event.message, Observation):
                seen[event.message.robot].add(event.message.step)
        assert all(len(steps) >= 5 for steps in seen.values()), seen
    for sim in sims:
        stop(sim)


def test_episode_events_and_outcome_on_the_terminal_observation(
    spawn, router, session_id, policy, tmp_path
):
    tiny = tmp_path / "tiny.toml"  # the goal right ahead: reached in a few steps
    tiny.write_text(
        'name = "tiny"\nsize = [3.0, 2.0]\ntimeout = 5.0\n'
        "[start]\npose = [0.6, 1.0, 0.0]\n[goal]\ncenter = [1.3, 1.0]\nradius = 0.3\n"
    )
    sim = start_lockstep(
        spawn,
        router,
        session_id,
        "--task",
        str(tiny),
    )
    wait_for_sim(policy)
    out = policy.output("action", robot_key(session_id, "r1", "action"))
    seen: list = []  # everything, in arrival order: which is kept per key, not across keys

    def next_observation() -> Observation:
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline:
            event = policy.poll(0.1)
            if isinstance(event, Input):
                seen.append(event.message)
                if isinstance(event.message, Observation):
                    return event.message
        pytest.fail("no observation within 15 s")

    obs = next_observation()  # the start of episode 0
    while obs.outcome == "running" and obs.episode_step < 12:
        out.put(act(obs.step, v=0.7))
        obs = next_observation()
    terminal = obs
    assert terminal.outcome == "goal" and terminal.reward == 99.0
    start = next_observation()  # no action for the terminal step: the next episode begins
    assert start.episode == 1 and start.episode_step == 0 and start.step == terminal.step + 1
    seen += quiet(policy, 0.3)
    events = {(m.kind, m.episode) for m in seen if isinstance(m, EpisodeEvent)}
    assert {("goal", 0), ("start", 1)} <= events
    stop(sim)


@pytest.mark.parametrize(
    ("argv", "error"),
    [
        (["--task", "9"], "unknown map '9'"),
        (["--robot", "r/1"], "robot: 'r/1' contains '/'"),
        (["--rtf", "0"], "--rtf and --action-timeout must be > 0"),
    ],
)
def test_bad_settings_are_clear_errors(router, session_id, argv, error):
    result = subprocess.run(
        [VOXSHAPE, "sim", *bus_args(router, session_id, "sim"), *argv],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2 and error in result.stderr, result.stderr
    assert "Traceback" not in result.stderr


def test_map_picture(tmp_path):
    path = tmp_path / "task3.png"
    track = tmp_path / "path.csv"
    track.write_text("x,y\n1.0,1.0\n2.0,1.5\n3.0,1.8\n")
    result = subprocess.run(
        [
            VOXSHAPE,
            "map",
            "3",
            "--png",
            str(path),
            "--trajectory",
            str(track),
            "--scan-at",
            "1,1,45",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    picture = matplotlib.image.imread(path)
    assert picture.shape[0] > 300 and picture.shape[1] > 300 and picture.std() > 0.05


def test_the_benchmark_prints_its_figures():
    result = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "sim.py"), "--json", "--steps", "300"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    figures = json.loads(result.stdout)
    print(figures)
    for key in ("in_process_steps_per_s", "realtime_factor", "bus_lockstep_steps_per_s"):
        assert figures[key] > 0
    assert figures["bus_action_to_next_obs_n"] > 250  # of the 300 steps, bar episodes' ends
    assert figures["realtime_factor"] == pytest.approx(
        figures["in_process_steps_per_s"] / 10, rel=0.01
    )

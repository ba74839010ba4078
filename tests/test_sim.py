"""The simulator's core: maps, drive, sensors (against PyBullet's own ray test), episodes,
rewards, and the Gymnasium environment."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pybullet as pb
import pytest
from gymnasium.utils.env_checker import check_env

from voxshape.services.learner.config import LearnerConfig
from voxshape.services.sim.gym_env import NavigationEnv
from voxshape.services.sim.sensors import Sensors
from voxshape.services.sim.task import Rewards, SimConfig, Simulation
from voxshape.services.sim.world import SENSOR_HEIGHT, World
from voxshape.world.maps import TASKS, MapError, Pose, load_map
from voxshape.world.robot import RobotModel

MODEL = RobotModel()


# -- maps ---------------------------------------------------------------------------------


@pytest.mark.parametrize("task", sorted(TASKS))
def test_every_task_loads_and_its_goal_is_reachable(task):
    m = load_map(task)
    distances = m.grid.distances_to_goal(0.22)
    from_start = distances[m.grid.cell(m.start.x, m.start.y)]
    straight = math.hypot(m.goal_x - m.start.x, m.goal_y - m.start.y)
    assert straight - m.goal_radius - 0.1 <= from_start < 3 * straight


def test_geodesic_distance_goes_around_walls():
    m = load_map("4")  # the door is at x = 5, y 2.5-3.5; start at (1.5, 1.5)
    d = m.grid.distances_to_goal(0.22)
    below_door, above_wall = d[m.grid.cell(4.5, 1.0)], d[m.grid.cell(5.5, 1.0)]
    assert below_door > above_wall + 1.5  # 1 m apart in a straight line, not around the wall


def write_map(tmp_path, body: str):
    path = tmp_path / "map.toml"
    path.write_text('name = "test"\nsize = [4.0, 4.0]\ntimeout = 10.0\n' + body)
    return path


GOOD = "[start]\npose = [1.0, 1.0, 0.0]\n[goal]\ncenter = [3.0, 3.0]\nradius = 0.4\n"


def test_a_users_own_map_file(tmp_path):
    m = load_map(write_map(tmp_path, "walls = [[2.0, 0.0, 2.0, 2.5]]\n" + GOOD))
    assert m.name == "test" and len(m.shapes) == 5


@pytest.mark.parametrize(
    ("body", "error"),
    [
        ("walls = [[0.0, 1.0, 4.0, 1.0]]\n" + GOOD, "would overlap a wall or obstacle"),
        ("[[cylinders]]\ncenter = [1.2, 1.0]\nradius = 0.2\n" + GOOD, "would overlap"),
        ("walls = [[0.0, 2.0, 4.0, 2.0]]\n" + GOOD, "unreachable from the start"),
        (GOOD.replace("[1.0, 1.0, 0.0]", "[5.0, 1.0, 0.0]"), "outside the 4 x 4 m floor"),
        (GOOD.replace("[3.0, 3.0]", "[9.0, 3.0]"), "[goal]: (9, 3) is outside the floor"),
        (GOOD.replace("[1.0, 1.0, 0.0]", "[1.0, 1.0]"), "expected a list of 3 numbers"),
        (GOOD.replace("radius = 0.4", 'radius = "big"'), "expected a number"),
        ("colour = 3\n" + GOOD, "unknown key 'colour'"),
        ("[[boxes]]\ncenter = [2.0, 2.0]\n" + GOOD, "size"),
        ("walls = [[1.0, 1.0, 1.0, 1.0]]\n" + GOOD, "the two ends are the same point"),
        ("[goal]\ncenter = [3.0, 3.0]\nradius = 0.4\n", "needs a [start] table"),
        (GOOD + "[extra\n", "not valid TOML"),
    ],
)
def test_bad_maps_get_clear_errors(tmp_path, body, error):
    with pytest.raises(MapError, match=re_escape(error)):
        load_map(write_map(tmp_path, body))


def re_escape(text: str) -> str:
    import re

    return re.escape(text)


def test_unknown_map_says_what_is_known():
    with pytest.raises(MapError, match=r"unknown map 'moon': give a task number \(1, 2, 3, 4\)"):
        load_map("moon")


# -- drive and collisions -----------------------------------------------------------------


def open_room(**config):
    sim = Simulation(load_map("1"), config=SimConfig(**config), seed=0)
    return sim


def test_drive_is_exact_unicycle_kinematics():
    sim = open_room()
    sim.reset("r1")
    sim.world.place(0, Pose(2.0, 2.0, 0.0))
    for _ in range(10):  # 1 s at 0.5 m/s
        r = sim.step({"r1": (0.5, 0.0)})["r1"]
    assert (r.pose.x, r.pose.y) == pytest.approx((2.5, 2.0), abs=1e-9)
    for _ in range(10):  # 1 s turning on the spot at 1 rad/s
        r = sim.step({"r1": (0.0, 1.0)})["r1"]
    assert r.pose.theta == pytest.approx(1.0, abs=1e-9)
    for _ in range(10):  # an arc of radius v / omega = 0.5 m for 1 s
        r = sim.step({"r1": (0.5, 1.0)})["r1"]
    centre = (2.5 - 0.5 * math.sin(1.0), 2.0 + 0.5 * math.cos(1.0))
    assert math.dist((r.pose.x, r.pose.y), centre) == pytest.approx(0.5, abs=1e-9)
    assert r.pose.theta == pytest.approx(2.0, abs=1e-9)


def test_commands_are_clipped_to_the_pioneer_limits():
    assert MODEL.clip(2.0, -9.0) == (0.7, -math.radians(100), True)
    assert MODEL.clip(0.3, 0.1) == (0.3, 0.1, False)
    sim = open_room()
    sim.reset("r1")
    sim.world.place(0, Pose(2.0, 2.0, 0.0))
    r = sim.step({"r1": (5.0, 0.0)})["r1"]
    assert r.pose.x == pytest.approx(2.07) and r.v == 0.7


def test_a_collision_stops_the_robot_before_it_overlaps_and_ends_the_episode():
    sim = open_room(collision="end")
    sim.reset("r1")
    sim.world.place(0, Pose(5.0, 3.0, 0.0))  # facing the east wall at x = 6
    for _ in range(100):
        r = sim.step({"r1": (0.7, 0.0)})["r1"]
        if r.outcome != "running":
            break
    assert r.outcome == "collision" and r.collided
    assert r.reward == Rewards().step + Rewards().collision
    front = r.pose.x + MODEL.length / 2
    # stopped within one sub-step of the wall, then backed off by the bumper reflex
    assert 6.0 - MODEL.recoil - 0.7 * 0.1 / 4 <= front < 6.0 - MODEL.recoil + 1e-9
    slant = math.cos(math.radians(0.5))  # beam 90 points 0.5 degrees left of ahead
    assert r.laser[90] == pytest.approx((6.0 - (r.pose.x + MODEL.laser_x)) / slant, abs=1e-9)


@pytest.mark.parametrize("turn", [1, -1])
def test_a_bump_backs_the_robot_off_so_that_an_arc_turns_away_from_the_wall(turn):
    sim = open_room(collision="continue")
    sim.reset("r1")
    sim.world.place(0, Pose(5.0, 3.0, 0.0))  # squarely facing the east wall at x = 6
    for _ in range(30):
        r = sim.step({"r1": (0.7, 0.0)})["r1"]
        if r.collided:
            break
    assert r.collided and r.pose.x + MODEL.length / 2 <= 6.0 - MODEL.recoil + 1e-9
    arc = LearnerConfig().velocities["left"]  # the learner's arc: 0.3 m/s at 60 degrees/s
    for _ in range(15):  # 90 degrees along the arc: no corner reaches the wall
        r = sim.step({"r1": (arc[0], turn * arc[1])})["r1"]
        assert not r.collided
    assert r.pose.theta == pytest.approx(turn * math.pi / 2, abs=0.02)


def test_collision_can_cost_a_penalty_and_go_on():
    sim = open_room(collision="continue")
    sim.reset("r1")
    sim.world.place(0, Pose(5.74, 3.0, 0.0))  # front 3.5 cm from the wall: hit in one step
    r = sim.step({"r1": (0.7, 0.0)})["r1"]
    assert (r.outcome, r.collided, r.reward, r.v) == ("running", True, -101.0, 0.0)
    r = sim.step({"r1": (-0.5, 0.0)})["r1"]  # backs away freely
    assert not r.collided and r.reward == -1.0


def test_robots_collide_with_each_other_and_see_each_other():
    sim = Simulation(load_map("1"), ("a", "b"), SimConfig(collision="end"), seed=0)
    sim.reset_all()
    sim.world.place(0, Pose(2.0, 3.0, 0.0))
    sim.world.place(1, Pose(3.0, 3.0, math.pi))
    laser, _ = sim.sensors.scan(sim.world.poses)
    slant = math.cos(math.radians(0.5))
    assert laser[0][90] == pytest.approx((3.0 - 0.225 - 2.15) / slant, abs=1e-9)  # b's back
    for _ in range(10):  # head on: 0.55 m apart, closing at 1.4 m/s
        r = sim.step({"a": (0.7, 0.0), "b": (0.7, 0.0)})
        if any(reading.outcome != "running" for reading in r.values()):
            break
    assert "collision" in {r["a"].outcome, r["b"].outcome}
    gap = (r["b"].pose.x - r["a"].pose.x) - MODEL.length
    # they stopped within one sub-step, not overlapping; the one that bumped backed off
    assert MODEL.recoil < gap < MODEL.recoil + 0.7 * 0.1 / 4


# -- sensors against PyBullet's own ray test ----------------------------------------------


def bullet_laser(world: World, pose: Pose) -> np.ndarray:
    """The laser computed independently with pybullet.rayTestBatch on the same world."""
    a = pose.theta + MODEL.laser_angles()
    lx = pose.x + MODEL.laser_x * math.cos(pose.theta)
    ly = pose.y + MODEL.laser_x * math.sin(pose.theta)
    sx, sy = np.full_like(a, lx), np.full_like(a, ly)  # the body is moved out of the way
    ex, ey = lx + MODEL.laser_max * np.cos(a), ly + MODEL.laser_max * np.sin(a)
    z = np.full_like(a, SENSOR_HEIGHT)
    hits = pb.rayTestBatch(
        np.stack([sx, sy, z], 1), np.stack([ex, ey, z], 1), physicsClientId=world.client
    )
    fraction = np.array([h[2] for h in hits])
    hit_x = sx + fraction * (ex - sx)
    hit_y = sy + fraction * (ey - sy)
    return np.clip(np.hypot(hit_x - lx, hit_y - ly), MODEL.laser_min, MODEL.laser_max)


@pytest.mark.parametrize("task", sorted(TASKS))
def test_laser_matches_pybullet_ray_test(task):
    m = load_map(task)
    world = World(m, 1)
    sensors = Sensors(m, MODEL)
    rng = np.random.default_rng(int(task))
    beams = close = 0
    try:
        for _ in range(40):
            while True:
                x, y = rng.uniform(0.3, m.width - 0.3), rng.uniform(0.3, m.height - 0.3)
                if m.clearance(x, y) > 0.35:
                    break
            pose = Pose(x, y, rng.uniform(-math.pi, math.pi))
            world.place(0, Pose(-50, -50, 0))  # keep the body out of the oracle's rays
            ours = sensors.scan([pose])[0][0]
            theirs = bullet_laser(world, pose)
            beams += len(ours)
            close += int(np.sum(np.abs(ours - theirs) < 0.01))
    finally:
        world.close()
    # Only beams grazing a cylinder differ: PyBullet tests its 32-sided prism, we the circle.
    assert close / beams > 0.995, f"{beams - close} of {beams} beams differ by 1 cm or more"


def random_poses(m, rng: np.random.Generator, n: int) -> list[Pose]:
    return [
        Pose(rng.uniform(0.2, m.width - 0.2), rng.uniform(0.2, m.height - 0.2), rng.uniform(-4, 4))
        for _ in range(n)
    ]


@pytest.mark.parametrize("task", sorted(TASKS))
def test_compiled_scan_equals_the_numpy_reference_to_the_bit(task):
    m = load_map(task)
    compiled, reference = Sensors(m, MODEL), Sensors(m, MODEL, compiled=False)
    rng = np.random.default_rng(int(task))
    for i in range(150):
        poses = random_poses(m, rng, 1 + i % 3)  # one to three robots, seeing each other
        laser, sonar = compiled.scan(poses)
        want_laser, want_sonar = reference.scan(poses)
        assert laser.tobytes() == want_laser.tobytes()
        assert sonar.tobytes() == want_sonar.tobytes()
        near_laser, near_sonar = compiled.scan(poses, reach=0.6)  # the same within reach
        assert np.array_equal(near_laser, np.where(laser < 0.6, laser, MODEL.laser_max))
        assert np.array_equal(near_sonar, np.where(sonar < 0.6, sonar, MODEL.sonar_max))


@pytest.mark.parametrize("task", sorted(TASKS))
def test_footprint_clearance_is_the_distance_from_the_robots_outline(task):
    from voxshape.services.sim.planar import footprint_clearance

    m = load_map(task)
    rng = np.random.default_rng(int(task))
    hl, hw = MODEL.length / 2, MODEL.width / 2
    edge = np.linspace(-1, 1, 201)
    outline = np.concatenate(  # points along the footprint's edges, in the robot frame
        [np.stack([hl * edge, np.full_like(edge, s * hw)], 1) for s in (-1, 1)]
        + [np.stack([np.full_like(edge, s * hl), hw * edge], 1) for s in (-1, 1)]
    )
    for pose in random_poses(m, rng, 300):
        c, s = math.cos(pose.theta), math.sin(pose.theta)
        px = pose.x + c * outline[:, 0] - s * outline[:, 1]
        py = pose.y + s * outline[:, 0] + c * outline[:, 1]
        sampled = max(float(m.clearance(px, py).min()), 0.0)
        ours = footprint_clearance(pose.x, pose.y, pose.theta, hl, hw, *m.outlines())
        assert ours <= sampled + 1e-9  # never more room than there is
        assert ours >= sampled - 0.005  # the samples lie 4 mm apart


@pytest.mark.parametrize("task", sorted(TASKS))
def test_culled_contacts_drive_exactly_as_a_query_at_every_substep(task):
    m = load_map(task)
    rng = np.random.default_rng(int(task))
    commands = [(rng.uniform(-0.3, 0.7), rng.uniform(-1.7, 1.7)) for _ in range(600)]
    trajectories = []
    for fast in (True, False):
        sim = Simulation(m, ("a", "b"), SimConfig(fast=fast), seed=int(task))
        sim.reset_all()
        trajectory = []
        for v, omega in commands:  # wanders, bumps into walls and into the other robot
            readings = sim.step({"a": (v, omega), "b": (omega / 2, v)})
            trajectory += [(r.pose, r.collided) for r in readings.values()]
        sim.close()
        trajectories.append(trajectory)
    assert trajectories[0] == trajectories[1]
    assert any(collided for _, collided in trajectories[0])


def test_sonar_sees_what_is_behind():
    sim = open_room()
    sim.reset("r1")
    sim.world.place(0, Pose(1.0, 3.0, 0.0))  # the west wall 1 m behind
    _, sonar = sim.sensors.scan(sim.world.poses)
    rear = MODEL.sonar_angles.index(math.radians(170))
    assert sonar[0][rear] == pytest.approx(1.0 - 0.225, abs=0.02)
    side = MODEL.sonar_angles.index(math.radians(90))  # 3 m to the north wall, minus body
    assert sonar[0][side] == pytest.approx(3.0 - 0.19, abs=0.05)


def test_sensor_noise_is_seeded_and_bounded():
    a = open_room(laser_noise=0.05, sonar_noise=0.05)
    b = open_room(laser_noise=0.05, sonar_noise=0.05)
    ra, rb = a.reset("r1"), b.reset("r1")
    assert np.array_equal(ra.laser, rb.laser) and np.array_equal(ra.sonar, rb.sonar)
    clean = open_room().reset("r1")
    assert 0.02 < np.std(ra.laser - clean.laser) < 0.1
    assert ra.laser.min() >= MODEL.laser_min and ra.laser.max() <= MODEL.laser_max


# -- episodes -----------------------------------------------------------------------------


def test_goal_ends_the_episode_with_its_reward_and_steps_keep_counting():
    sim = open_room()
    first = sim.reset("r1")
    sim.world.place(0, Pose(4.3, 4.3, math.pi / 4))
    r = sim.step({"r1": (0.7, 0.0)})["r1"]
    while r.outcome == "running":
        r = sim.step({"r1": (0.7, 0.0)})["r1"]
    assert r.outcome == "goal" and r.reward == Rewards().step + Rewards().goal
    again = sim.reset("r1")
    assert (again.episode, again.step, again.episode_step) == (1, r.step + 1, 0)
    assert first.step == 0


def test_timeout_truncates_the_episode():
    sim = open_room(timeout=1.0)
    sim.reset("r1")
    outcomes = [sim.step({"r1": (0.0, 0.3)})["r1"].outcome for _ in range(10)]
    assert outcomes == ["running"] * 9 + ["timeout"]
    with pytest.raises(ValueError, match="reset it first"):
        sim.step({})


def test_a_reset_is_fast_and_bit_identical():
    sim = open_room()
    sim.seed(7)
    first = sim.reset("r1")
    for _ in range(30):
        sim.step({"r1": (0.5, 0.4)})
    sim.seed(7)
    again = sim.reset("r1")
    assert first.pose == again.pose and np.array_equal(first.laser, again.laser)


# -- Gymnasium ----------------------------------------------------------------------------


@pytest.mark.parametrize("task", sorted(TASKS))
def test_gymnasium_env_checker_passes(task):
    env = NavigationEnv(task, render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # advice only: physical units, not [-1, 1]
        check_env(env, skip_render_check=False)
    env.close()


def rollout(seed: int, steps: int = 300) -> list:
    env = gym.make("voxshape/Navigation-v0", task="3")
    obs, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    trace = [obs]
    for _ in range(steps):
        obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        trace.append((obs, reward))
        if terminated or truncated:
            trace.append(env.reset()[0])
    env.close()
    return trace


def flat(trace: list) -> np.ndarray:
    parts = []
    for item in trace:
        obs, reward = item if isinstance(item, tuple) else (item, 0.0)
        parts += [*(np.ravel(v) for v in obs.values()), np.array([reward])]
    return np.concatenate(parts)


def test_seeded_runs_are_bit_identical():
    a, b, c = flat(rollout(11)), flat(rollout(11)), flat(rollout(12))
    assert a.tobytes() == b.tobytes()
    assert a.shape != c.shape or a.tobytes() != c.tobytes()


def test_render_gives_a_picture():
    env = NavigationEnv("4", render_mode="rgb_array")
    env.reset(seed=0)
    env.step(np.array([0.5, 0.2], np.float32))
    picture = env.render()
    assert picture.ndim == 3 and picture.shape[2] == 3 and picture.std() > 10
    env.close()


def test_several_robots_start_apart_and_clear_of_each_other():
    sim = Simulation(load_map("1"), ("a", "b", "c"), seed=0)
    readings = sim.reset_all()
    poses = [r.pose for r in readings.values()]
    for i, p in enumerate(poses):
        assert sim.map.clearance(p.x, p.y) >= 0.3
        for q in poses[i + 1 :]:
            assert math.dist((p.x, p.y), (q.x, q.y)) > MODEL.length
    first = sim.step({name: (0.0, 0.0) for name in sim.robots})
    assert all(not r.collided for r in first.values())


def test_the_map_format_the_docs_show_loads_with_every_key(tmp_path):
    """docs/simulator.md#your-own-map is the format's one description: its example loads."""
    doc = (Path(__file__).parents[1] / "docs" / "simulator.md").read_text()
    example = doc.split("## Your own map", 1)[1].split("```toml\n", 1)[1].split("```", 1)[0]
    path = tmp_path / "mine.toml"
    path.write_text(example)
    m = load_map(str(path))
    assert m.name == "Task 1: open room" and m.timeout == 60.0
    for key in ("walls", "wall_thickness", "[[boxes]]", "[[cylinders]]", "jitter", "angle"):
        assert key in example

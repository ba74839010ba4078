"""The bridge's pure core: a real robot's scans and odometry as the simulator's observations,
episodes told as the simulator tells them, what may move the robot (safety first), and the
way back to the start between episodes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.ros2_robot import cast as ray_cast
from voxshape.protocol import Action, EpisodeEvent, Observation, Placed
from voxshape.services.ros2 import msgs
from voxshape.services.ros2.bridge import Bridge, BridgeConfig, InsideRadius
from voxshape.services.ros2.contact import Contact, ContactConfig
from voxshape.services.ros2.episodes import BridgePercept, EpisodeRules, Episodes
from voxshape.services.ros2.homing import HomingConfig, homing_command
from voxshape.services.ros2.perception import (
    AROUND,
    Anchor,
    ScanGeometry,
    around_angles,
    around_from_scan,
    laser_from_scan,
    sonar_from_scan,
    yaw_of,
)
from voxshape.services.ros2.safety import STOP, Limits, Safety
from voxshape.services.sim.task import Simulation
from voxshape.world.maps import load_map
from voxshape.world.robot import RobotModel
from voxshape.world.task import Goal, Rewards

MODEL = RobotModel()
FULL = ScanGeometry(0.0, 2 * math.pi / 360, 0.12, 3.5)  # a TurtleBot's 360 beams


def test_a_full_turn_scan_reads_as_the_simulator_s_front_beams():
    ranges = np.full(360, 3.0, np.float32)
    ranges[0] = 1.0  # straight ahead
    ranges[89] = 2.0  # left
    laser = laser_from_scan(ranges, FULL, MODEL)
    assert laser.shape == (180,)
    assert laser[90] == pytest.approx(1.0)  # the slot [0, 1) degrees
    assert laser[178:].min() == pytest.approx(2.0)  # 89 degrees: a slot's edge, either side
    assert laser.max() == pytest.approx(3.0)


def test_inf_nan_and_out_of_range_readings_mean_what_rep_117_says():
    ranges = np.full(360, np.nan, np.float32)
    ranges[0], ranges[1], ranges[359] = np.inf, 0.0, -np.inf  # far, no return, too close
    ranges[10] = 9.0  # beyond range_max: nothing within it
    laser = laser_from_scan(ranges, FULL, MODEL)
    angles = np.degrees(MODEL.laser_angles())
    assert laser[np.abs(angles - 10.5).argmin()] == MODEL.laser_max
    assert laser[np.abs(angles - 0.5).argmin()] == MODEL.laser_max  # inf, and 0.0 ignored
    assert laser[np.abs(angles + 0.5).argmin()] == MODEL.laser_min  # -inf: too close
    assert np.all(laser[np.abs(angles) > 12] == MODEL.laser_max)  # NaN: nothing known
    assert np.isfinite(sonar_from_scan(ranges, FULL, MODEL)).all()


def test_a_coarse_or_narrow_scan_fills_the_simulator_s_beams():
    coarse = ScanGeometry(-math.pi, math.tau / 90, 0.1, 10.0)  # 4 degrees a beam
    laser = laser_from_scan(np.full(90, 2.5, np.float32), coarse, MODEL)
    assert np.allclose(laser, 2.5)
    narrow = ScanGeometry(-math.radians(45), math.radians(1), 0.1, 10.0)  # 90 degrees ahead
    laser = laser_from_scan(np.full(91, 1.5, np.float32), narrow, MODEL)
    angles = np.degrees(MODEL.laser_angles())
    assert np.allclose(laser[np.abs(angles) < 44], 1.5)
    assert np.all(laser[np.abs(angles) > 47] == MODEL.laser_max)
    sonar = sonar_from_scan(np.full(91, 1.5, np.float32), narrow, MODEL)
    assert np.all(sonar == MODEL.sonar_max)  # it does not look behind


def test_sonars_read_the_rear_beams_from_the_body():
    ranges = np.full(360, 3.0, np.float32)
    ranges[175:186] = 1.0  # behind
    sonar = sonar_from_scan(ranges, FULL, MODEL)
    behind = [i for i, a in enumerate(MODEL.sonar_angles) if abs(abs(a) - math.radians(170)) < 1e-6]
    body = MODEL.length / 2 / abs(math.cos(math.radians(170)))
    assert all(sonar[i] == pytest.approx(1.0 - body, abs=1e-6) for i in behind)


def rules(max_steps: int = 1000, radius: float = 0.25) -> EpisodeRules:
    return EpisodeRules(Goal(5.0, 5.0, 0.5), ContactConfig(radius), max_steps)


def percept(x: float = 1.0, y: float = 1.0, near: float = 3.0, theta: float = 0.0):
    return BridgePercept(
        x, y, theta, 0.1, 0.0, np.full(180, near), np.full(8, 3.0), np.full(AROUND, near)
    )


def test_the_bridge_tells_a_pose_as_the_simulator_does():
    """The same task, the same pose: the bridge's observation carries the simulator's goal
    distance and bearing, and its steps the simulator's rewards (voxshape/world/task.py)."""
    m = load_map("1")
    sim = Simulation(m, ("r1",), seed=3)
    try:
        reading = sim.reset("r1")
    finally:
        sim.close()
    episodes = Episodes("r1", EpisodeRules(m.goal, ContactConfig(0.2), 1000))
    p = percept(reading.x, reading.y, theta=reading.theta)
    _, first = episodes.start(p, 0.0)
    assert (first.goal_distance, first.goal_bearing) == (
        reading.goal_distance,
        reading.goal_bearing,
    )
    (step,) = episodes.advance(p, 0.1)
    assert step.reward == Rewards().step


def test_episodes_end_at_the_goal_at_a_bump_and_at_the_timeout():
    episodes = Episodes("r1", rules(max_steps=3))
    start = episodes.start(percept(), 0.0)
    assert [type(m) for m in start] == [EpisodeEvent, Observation]
    assert start[0].kind == "start" and start[1].episode_step == 0 and start[1].reward == 0.0
    (obs,) = episodes.advance(percept(), 0.1)
    assert (obs.outcome, obs.reward, obs.step) == ("running", -1.0, 1)
    obs, end = episodes.advance(percept(4.8, 4.9), 0.2)
    assert (obs.outcome, obs.reward, end.kind, end.env_return) == ("goal", 99.0, "goal", 98.0)
    episodes.start(percept(), 0.3)
    obs, end = episodes.advance(percept(near=0.2), 0.4)
    assert (obs.outcome, obs.collided, obs.reward, end.kind) == (
        "collision",
        True,
        -101,
        "collision",
    )
    first = episodes.start(percept(), 0.5)[1]
    assert first.step == obs.step + 1 and first.episode == 2  # as the simulator counts
    outcomes = [episodes.advance(percept(), 0.6)[0].outcome for _ in range(3)]
    assert outcomes == ["running", "running", "timeout"]


def test_a_bump_is_the_nearest_reading_all_round_or_odometry_stuck():
    ranges = np.full(360, 3.0, np.float32)
    ranges[175:186] = 0.15  # just behind: no laser beam looks there
    around = around_from_scan(ranges, FULL)
    assert laser_from_scan(ranges, FULL, MODEL).min() == pytest.approx(3.0)
    assert Contact(ContactConfig(0.2)).touching(around, 0.0, 1.0, 1.0, 0.0) == "scan"
    assert Contact(ContactConfig(0.1)).touching(around, 0.0, 1.0, 1.0, 0.0) is None
    clear = np.full(AROUND, np.inf)
    stuck = Contact(ContactConfig(0.2, stuck_after=0.5))
    # backing at 0.2 m/s: it moves for 0.3 s, then against a wall it stays put
    xs = [1.0, 0.98, 0.96, 0.94] + [0.94] * 8
    said = [stuck.touching(clear, 0.1 * k, x, 1.0, 0.2) for k, x in enumerate(xs)]
    assert said.index("stuck") == 7  # 0.4 s after it stopped moving, at t = 0.3 s
    still = Contact(ContactConfig(0.2, stuck_after=0.5))
    assert {still.touching(clear, 0.1 * k, 1.0, 1.0, 0.0) for k in range(12)} == {None}
    # a robot whose process stalls: its odometry's stamps stall too (same stamp, no step)
    stalled = Contact(ContactConfig(0.2, stuck_after=0.5))
    stamps = [0.0, 0.1, 0.2, 0.2, 0.2, 0.2, 0.2, 0.2, 0.3, 0.4, 0.5, 0.6]
    xs = [1.0 + 0.02 * len(set(stamps[: k + 1])) for k in range(len(stamps))]
    assert {stalled.touching(clear, t, x, 1.0, 0.2) for t, x in zip(stamps, xs, strict=True)} == {
        None
    }


def test_a_scan_that_does_not_look_behind_reads_unknown_there():
    narrow = ScanGeometry(-math.radians(45), math.radians(1), 0.1, 10.0)
    ranges = np.full(91, 1.5, np.float32)
    ranges[10:14] = np.inf  # nothing within range there
    around = around_from_scan(ranges, narrow)
    behind = np.abs(np.degrees(around_angles())) > 150
    assert np.isnan(around[behind]).all() and np.nanmin(around) == pytest.approx(1.5)
    assert np.isinf(around).any()


def test_a_command_lapses_and_stale_data_or_bus_stops_the_robot():
    safety = Safety(Limits(max_speed=0.3, max_turn=1.0, action_timeout=0.4), period=0.1)
    assert safety.go(0.5, -2.0, 0.0, fresh=True) == (0.3, -1.0)  # clipped
    assert safety.counters["clipped"] == 1
    assert safety.tick(0.39, fresh=True) is None
    assert safety.tick(0.41, fresh=True) == STOP  # lapsed: the learner is gone
    repeats = [safety.tick(0.41 + 0.1 * k, fresh=True) for k in range(1, 6)]
    assert repeats == [STOP, STOP, None, None, None]  # said three times, then quiet
    assert safety.go(0.2, 0.0, 1.0, fresh=False) == STOP  # the robot's data went stale
    assert safety.go(0.2, 0.0, 1.05, fresh=False) is None  # already said
    assert safety.go(0.2, 0.0, 1.1, fresh=True) == (0.2, 0.0)
    assert safety.tick(1.2, fresh=False) == STOP  # the bus went away while it moved
    assert safety.counters["stops.lapsed"] == 1 and safety.counters["stops.stale"] == 2
    with pytest.raises(ValueError, match="max-speed must be > 0"):
        Limits(max_speed=0)


def view(near: float = 5.0, **sectors: tuple[float, float, float]) -> np.ndarray:
    """An all-round view: `near` everywhere, but (from_deg, to_deg, metres) per sector."""
    around = np.full(AROUND, near)
    degrees = np.degrees(around_angles())
    for lo, hi, metres in sectors.values():
        around[(degrees >= lo) & (degrees <= hi)] = metres
    return around


def test_homing_drives_to_the_start_turns_there_and_avoids_what_is_ahead():
    start = (1.0, 1.0, 0.0)
    clear = view()
    v, w, arrived = homing_command((3.0, 1.0, math.pi), start, clear, 0.2)
    assert v > 0 and abs(w) < 0.1 and not arrived  # facing it: drive
    v, w, _ = homing_command((3.0, 1.0, 0.0), start, clear, 0.2)
    assert v == 0 and w != 0  # facing away: turn first
    v, w, _ = homing_command((3.0, 1.0, math.pi), start, view(ahead=(-10, 10, 0.3)), 0.2)
    assert v == 0 and w != 0
    v, _, _ = homing_command((3.0, 1.0, math.pi), start, view(ahead=(-10, 10, 0.1)), 0.2)
    assert v < 0  # nearer than the robot's radius, the way behind clear: back off
    v, w, arrived = homing_command((1.05, 1.0, 1.0), start, clear, 0.2)
    assert v == 0 and w < 0 and not arrived  # there: turn to the start heading
    assert homing_command((1.05, 1.0, 0.05), start, clear, 0.2)[2]


@pytest.mark.parametrize("behind", [(150, 180, 0.3), (-180, -160, 0.25)])
def test_homing_never_backs_into_what_the_scan_shows_behind(behind):
    squeezed = view(ahead=(-10, 10, 0.1), behind=behind)
    v, w, _ = homing_command((3.0, 1.0, math.pi), (1.0, 1.0, 0.0), squeezed, 0.2)
    assert v == 0 and w != 0  # turns in place instead
    blind = view(ahead=(-10, 10, 0.1), behind=(90, 180, np.nan), other=(-180, -90, np.nan))
    v, _, _ = homing_command((3.0, 1.0, math.pi), (1.0, 1.0, 0.0), blind, 0.2)
    assert v == 0  # a scan that does not look behind: it never backs blind


def test_a_placed_robot_s_odometry_reads_the_start_there():
    anchor = Anchor.placing((2.0, -1.0, 1.0), (1.0, 1.0, 0.3))
    x, y, theta = anchor.apply(2.0, -1.0, 1.0)
    assert (x, y, theta) == pytest.approx((1.0, 1.0, 0.3))
    assert yaw_of(0, 0, math.sin(0.35), math.cos(0.35)) == pytest.approx(0.7)


# -- the core on its inputs -------------------------------------------------------------------
def scan(near: float = 3.0) -> msgs.LaserScanMsg:
    return msgs.LaserScanMsg(
        msgs.HeaderMsg(), 0.0, math.tau, math.tau / 360, 0, 0.1, 0.12, 3.5,
        np.full(360, near, np.float32),
    )  # fmt: skip


def odom(x: float, y: float, theta: float = 0.0) -> msgs.OdometryMsg:
    q = (0.0, 0.0, math.sin(theta / 2), math.cos(theta / 2))
    return msgs.OdometryMsg(msgs.HeaderMsg(), "base_link", (x, y, 0.0), q)


def act(episode: int, v: float = 0.2, robot: str = "r1") -> Action:
    return Action(
        robot=robot, episode=episode, step=0, discrete=1, v=v, omega=0.0, chooser="policy"
    )


def bridge(reset: str = "drive", max_steps: int = 1000) -> Bridge:
    config = BridgeConfig(
        rules(max_steps), "r1", reset, limits=Limits(max_speed=0.5), homing=HomingConfig()
    )
    return Bridge(config, now=0.0)


def step(b: Bridge, t: float, x: float, y: float, theta: float = 0.0, near: float = 3.0):
    b.on_odom(odom(x, y, theta), t)
    return b.on_scan(scan(near), t)


def test_each_scan_a_period_apart_is_a_step_and_actions_pass_at_once():
    b = bridge()
    first = step(b, 0.0, 1.0, 1.0)
    assert [m.TYPE for m in first.messages] == ["episode", "observation"]
    assert step(b, 0.05, 1.0, 1.0).messages == []  # too soon: a scan between steps
    (obs,) = step(b, 0.1, 1.1, 1.0).messages
    assert (obs.step, obs.x, obs.episode_step) == (1, pytest.approx(1.1), 1)
    assert b.on_action(act(0), 0.11).velocity == (0.2, 0.0)
    assert b.on_action(act(7), 0.12).velocity is None  # another episode's: late
    assert b.on_action(act(0, robot="r2"), 0.12).velocity is None
    assert b.counters["actions.ignored.not_running"] == 1
    assert b.tick(0.6, bus_ok=True).velocity == STOP  # no new action: it lapsed


def test_no_step_without_fresh_data_and_a_step_late_without_a_scan():
    b = bridge()
    step(b, 0.0, 1.0, 1.0)
    b.on_odom(odom(1.0, 1.0), 0.1)
    assert b.tick(0.12, True).messages == []  # a scan may still come
    (obs,) = b.tick(0.16, True).messages  # half a period late: the last scan again
    assert obs.step == 1
    assert b.tick(2.0, True).messages == []  # everything is stale now: no step
    assert b.on_action(act(0), 2.0).velocity == STOP


def test_an_episode_end_stops_the_robot_and_it_drives_back_to_the_start():
    b = bridge()
    step(b, 0.0, 1.0, 1.0)
    b.on_action(act(0), 0.01)
    out = step(b, 0.1, 4.9, 4.9)  # at the goal
    assert out.velocity == STOP and b.state == "homing"
    assert any("driving back" in n for n in out.notes)
    assert b.on_action(act(0), 0.12).velocity is None  # the ended episode's: ignored
    out = step(b, 0.2, 4.9, 4.9, theta=math.radians(225))  # facing the start
    assert out.velocity is not None and out.velocity[0] > 0 and out.messages == []
    out = step(b, 0.3, 1.05, 1.0, theta=0.0)  # back there
    assert [m.TYPE for m in out.messages] == ["episode", "observation"]
    assert out.messages[0].kind == "start" and out.messages[1].episode == 1
    assert b.state == "running" and b.counters["homing.arrived"] == 1


def test_a_waiting_robot_starts_again_once_placed_with_its_odometry_re_anchored():
    b = bridge(reset="wait")
    step(b, 0.0, 1.0, 1.0)
    step(b, 0.1, 1.0, 1.0, near=0.2)  # a bump
    assert b.state == "placing"
    assert b.on_placed(Placed(teacher="ana", robot="r2"), 0.15).messages == []
    step(b, 0.2, 3.0, 2.0, 1.0)  # carried back: odometry did not see it
    out = b.on_placed(Placed(teacher="ana", robot="r1"), 0.25)
    start, obs = out.messages
    assert start.kind == "start" and (obs.x, obs.y, obs.theta) == pytest.approx((1.0, 1.0, 0.0))
    (obs,) = step(b, 0.35, 3.1, 2.0, 1.0).messages
    assert obs.x == pytest.approx(1.0 + 0.1 * math.cos(-1.0), abs=1e-9)


def test_homing_that_cannot_get_back_waits_for_a_teacher():
    b = bridge()
    step(b, 0.0, 1.0, 1.0)
    step(b, 0.1, 1.0, 1.0, near=0.2)  # a bump ends it
    t = 0.2
    while b.state == "homing" and t < 200:
        out = step(b, t, 3.0, 3.0, near=0.2)  # boxed in: it never gets anywhere
        t += 0.1
    assert b.state == "placing" and b.counters["homing.gave_up"] == 1
    assert any("voxshape placed --robot r1" in n for n in out.notes)


@pytest.mark.parametrize("pose", [(5.6, 3.0, 0.0), (3.0, 5.6, math.pi / 2), (5.5, 5.5, 0.78)])
def test_homing_gets_back_from_a_wall_it_faces_without_touching_it(pose):
    """Task 1's room, the robot just off a wall it faces (as after a bump), the start behind
    it: it turns, drives back and stops at the start, never nearer the wall than it was."""
    m = load_map("1")
    segments, circles = m.outlines()
    start, (x, y, theta), dt = (1.0, 1.0, 0.0), pose, 0.1
    nearest = float(m.clearance(x, y))
    for _ in range(2000):
        around = ray_cast(x, y, theta + around_angles(), segments, circles)
        v, w, arrived = homing_command((x, y, theta), start, around, 0.25)
        if arrived:
            break
        theta += w * dt
        x, y = x + v * dt * math.cos(theta), y + v * dt * math.sin(theta)
        nearest = min(nearest, float(m.clearance(x, y)))
    assert arrived and math.hypot(x - 1.0, y - 1.0) <= 0.15
    assert nearest >= min(0.3, float(m.clearance(*pose[:2]))) - 0.05


def test_a_late_scan_does_not_push_the_next_ones_back():
    """Steps are due on a schedule: a scan 25 ms late is a step, and so is the next, on time,
    75 ms after it (a rule of a period since the last step would drop it); a 40 Hz lidar
    gives a step every fourth scan."""
    b = bridge()
    steps = [len(step(b, t, 1.0, 1.0).messages) for t in (0.0, 0.125, 0.2, 0.3)]
    assert steps == [2, 1, 1, 1]
    fast = bridge()
    taken = [bool(step(fast, 0.025 * k, 1.0, 1.0).messages) for k in range(17)]
    assert sum(taken) == 5 and taken[::4] == [True] * 5


def test_a_robot_that_starts_inside_its_radius_is_refused_and_later_warned():
    b = bridge()
    with pytest.raises(InsideRadius, match=r"reads 0\.15 m at .* inside the bump radius"):
        step(b, 0.0, 1.0, 1.0, near=0.15)
    b = bridge(reset="wait")
    step(b, 0.0, 1.0, 1.0)
    step(b, 0.1, 1.0, 1.0, near=0.2)  # a bump ends the first episode
    b.on_odom(odom(1.0, 1.0), 0.2)
    out = b.on_placed(Placed(teacher="ana", robot="r1"), 0.2)
    assert any(n.startswith("warning: the scan reads 0.20 m") for n in out.notes)
    assert b.counters["started_in_contact"] == 1


def test_a_robot_pushing_a_wall_backwards_ends_its_episode_and_stops():
    """Its scan sees nothing inside the radius (a radius no larger than the robot), but its
    odometry stands still while it is told to back: a bump, and a stop, within 0.6 s."""
    b = bridge()
    step(b, 0.0, 1.0, 1.0)
    k, out = 0, None
    for k in range(1, 20):
        b.on_action(act(0, v=-0.2), 0.1 * k - 0.05)
        out = step(b, 0.1 * k, 1.0, 1.0, near=0.3)  # against a wall: odometry does not move
        if b.state != "running":
            break
    assert out.velocity == STOP and out.messages[-1].kind == "collision"
    assert k <= 6 and b.counters["bumps.stuck"] == 1


def test_a_lidar_mounted_turned_is_read_in_the_robot_s_heading():
    """A TurtleBot 4's lidar frame is turned 90 degrees from its base (turtlebot4_description):
    with --scan-yaw its readings fall where they are around the robot, not 90 degrees off."""
    ranges = np.full(360, 3.0, np.float32)
    ranges[270] = 1.0  # the scan's own 270 degrees (its right) ...
    turned = BridgeConfig(rules(), "r1", limits=Limits(max_speed=0.5), scan_yaw=math.pi / 2)
    b = Bridge(turned, now=0.0)
    b.on_odom(odom(1.0, 1.0), 0.0)
    message = msgs.LaserScanMsg(msgs.HeaderMsg(), 0.0, math.tau, math.tau / 360, 0, 0.1, 0.12,
                                3.5, ranges)  # fmt: skip
    (_, obs) = b.on_scan(message, 0.0).messages
    assert obs.laser[90] == pytest.approx(1.0)  # ... is the robot's straight ahead
    assert min(obs.laser[:80] + obs.laser[100:]) == pytest.approx(3.0)

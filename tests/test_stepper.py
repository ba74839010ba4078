"""The simulator service's core without the bus: which actions count, and when it steps."""

from __future__ import annotations

import pytest

from voxshape.protocol import Action, EpisodeEvent, Observation
from voxshape.services.sim.stepper import Stepper
from voxshape.services.sim.task import Simulation
from voxshape.world.maps import load_map


def stepper(clock: str = "lockstep", timeout: float = 2.0, robots=("r1",)) -> Stepper:
    s = Stepper(Simulation(load_map("1"), robots, seed=0), clock, timeout)
    s.start()
    return s


def action(step: int, robot: str = "r1", v: float | None = 0.5, omega: float | None = 0.0):
    return Action(
        robot=robot, episode=0, step=step, discrete=None, v=v, omega=omega, chooser="policy"
    )


def test_start_announces_each_episode_then_observes():
    s = Stepper(Simulation(load_map("1"), ("a", "b"), seed=0), "lockstep", 2.0)
    messages = s.start()
    assert [type(m) for m in messages] == [EpisodeEvent, Observation] * 2
    assert [m.kind for m in messages if isinstance(m, EpisodeEvent)] == ["start", "start"]


def test_lockstep_is_ready_only_with_every_robots_action_for_its_step():
    s = stepper(robots=("a", "b"))
    assert not s.ready(now=s.waiting_since + 0.1)
    s.on_action("a", action(0, "a"))
    assert not s.ready(now=s.waiting_since + 0.1)
    s.on_action("b", action(0, "b"))
    assert s.ready(now=s.waiting_since + 0.1)
    messages = s.step(now=s.waiting_since + 0.1)
    assert [m.step for m in messages if isinstance(m, Observation)] == [1, 1]


def test_lockstep_wait_is_bounded_and_the_robot_stops():
    s = stepper(timeout=2.0)
    assert not s.ready(now=s.waiting_since + 1.9)
    assert s.ready(now=s.waiting_since + 2.0)
    (obs,) = s.step(now=s.waiting_since + 2.0)
    assert obs.v == 0.0 and s.counters["stopped_without_action"] == 1


@pytest.mark.parametrize(
    ("key_robot", "message", "reason"),
    [
        ("r1", action(0, robot="r2"), "ignored.robot_mismatch"),
        ("ghost", action(0, robot="ghost"), "ignored.unknown_robot"),
        ("r1", action(0, v=None, omega=None), "ignored.no_velocity"),
        ("r1", action(5), "ignored.early"),
    ],
)
def test_actions_that_cannot_be_used_are_counted_and_ignored(key_robot, message, reason):
    s = stepper()
    s.on_action(key_robot, message)
    assert s.counters[reason] == 1 and not s.commands


def test_late_action_is_ignored_in_lockstep():
    s = stepper()
    s.on_action("r1", action(0))
    s.step(now=s.waiting_since)
    s.on_action("r1", action(0))  # answers the step that is already done
    assert s.counters["ignored.late"] == 1


def test_out_of_range_action_is_clipped_and_counted():
    s = stepper()
    s.on_action("r1", action(0, v=9.0, omega=-9.0))
    (obs,) = s.step(now=s.waiting_since)
    assert (obs.v, round(obs.omega, 4)) == (0.7, -1.7453) and s.counters["clipped"] == 1


def test_paced_holds_the_last_action_until_it_is_stale():
    s = stepper(clock="paced", timeout=0.5)
    t = s.waiting_since
    s.on_action("r1", action(17))  # paced: any step, the latest wins
    received = s.commands["r1"].received
    assert s.step(now=received + 0.1)[0].v == 0.5
    assert s.step(now=received + 0.6)[0].v == 0.0
    assert s.stalled == {"r1"} and t <= received

"""The straight-line potential and what the learner does with it: potential-based shaping of
every update, a lookahead that stops where the laser shows a wall, a judging word credited to
the stretch it judges, and advice that speaks for where the robot was."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tests.learner_support import EXACT, FORWARD, WALL_LEFT, P
from voxshape.protocol import ACTION_NAMES
from voxshape.services.learner.config import LearnerConfig
from voxshape.services.learner.lookahead import reachable
from voxshape.services.learner.potential import StraightLine
from voxshape.services.learner.sarsa import Learner
from voxshape.world.maps import load_map

STRAIGHT = replace(EXACT, potential="straight_line", potential_scale=10.0)
CLEAR = (8.0,) * 180  # the laser sees nothing within 8 m
VELOCITY = np.array([(0.5, 0.0), (0.3, math.radians(60))])  # forward, an arc to the left


def test_the_straight_line_ranks_places_by_their_distance_to_the_goal():
    assert StraightLine((3.0, 0.0)).value(3.0, 4.0) == pytest.approx(-4.0)
    assert StraightLine().value(1.0, 0.0) == 0.0  # no goal seen yet: no potential


def _walk(learner: Learner, places: list[tuple[float, float]], first: int = 0) -> None:
    """Forward steps through `places`, the goal at (3, 0)."""
    for step, (x, y) in enumerate(places, first):
        p = P(WALL_LEFT, x=x, y=y, goal_distance=math.dist((x, y), (3.0, 0.0)), step=step)
        learner.step(p, forced=learner.actions.one_hot(FORWARD))


def test_the_potential_shapes_every_update_by_gamma_phi_next_minus_phi():
    learner = Learner(STRAIGHT, seed=0)
    _walk(learner, [(0.0, 0.0), (0.5, 0.0)])
    q_before, s = learner.q(learner.s).copy(), learner.s
    _walk(learner, [(1.0, 0.0)], first=2)  # 0.5 m nearer the goal
    c = STRAIGHT
    shaping = c.gamma * c.potential_scale * -2.0 - c.potential_scale * -2.5
    delta = -1.0 + shaping + c.gamma * learner.q(learner.s)[FORWARD] - q_before[FORWARD]
    assert learner.Q[s, FORWARD] - q_before[FORWARD] == pytest.approx(c.alpha * delta)


def test_the_lookahead_stops_each_arc_where_the_laser_shows_something():
    free = reachable((0.0, 0.0, 0.0), CLEAR, VELOCITY, 1.0)
    assert free[0] == pytest.approx((0.5, 0.0))
    wall_ahead = (8.0,) * 80 + (0.4,) * 20 + (8.0,) * 80  # 0.4 m straight ahead
    stopped = reachable((0.0, 0.0, 0.0), wall_ahead, VELOCITY, 1.0)
    assert 0.2 < stopped[0][0] < 0.3  # short of the wall (0.55 m ahead), with room to stop
    turned = reachable((1.0, 2.0, math.pi / 2), CLEAR, VELOCITY, 1.0)  # facing +y
    assert turned[0] == pytest.approx((1.0, 2.5))


def test_the_policy_heads_where_the_potential_expects_progress_and_not_into_a_wall():
    learner = Learner(replace(STRAIGHT, lookahead_weight=3.0), seed=0)
    left = ACTION_NAMES.index("left")
    learner.step(P(CLEAR, goal_distance=3.0, goal_bearing=math.pi / 2))  # to the left
    progress = learner._expected_progress()
    assert progress[left] > 0 > progress[FORWARD]  # forward leaves the line to the goal
    learner.interrupt()
    wall = (8.0,) * 80 + (0.1,) * 20 + (8.0,) * 80  # the goal straight ahead, behind a wall
    learner.step(P(wall, goal_distance=3.0, goal_bearing=0.0, step=1))
    assert learner._expected_progress()[FORWARD] == pytest.approx(0.0)  # no way through


def test_the_learner_builds_every_potential_it_is_given_and_refuses_an_oracle_without_a_map():
    task = load_map("docs/results/new-maps/uturn.toml")
    oracle = Learner(replace(STRAIGHT, potential="oracle"), seed=0, task=task)
    start, goal = (1.0, 1.5), (1.0, 4.6)  # the goal behind the long wall
    assert oracle.way.phi(goal) > oracle.way.phi((7.4, 2.0)) > oracle.way.phi(start)
    assert oracle.way.phi(start) < -math.dist(start, goal) - 5  # the way round, not the line
    assert Learner(replace(STRAIGHT, potential="none"), seed=0).way.guess is None
    with pytest.raises(ValueError, match="potential=oracle needs the map"):
        Learner(replace(STRAIGHT, potential="oracle"), seed=0)


def test_the_simulator_senses_as_far_as_the_lookahead_looks():
    looking = Learner(LearnerConfig())  # the defaults: the near bits read 0.6 m
    farthest = 0.5 * 1.0 + 0.15 + 0.275  # forward for lookahead_s, the laser's offset, ROOM
    assert looking.reach == pytest.approx(farthest) and looking.states.reach == 0.6
    blind = Learner(LearnerConfig(lookahead_weight=0.0))
    assert blind.reach == blind.states.reach == 0.6

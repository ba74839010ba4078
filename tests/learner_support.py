"""Crafted percepts, configurations and episodes the learner's tests share."""

from __future__ import annotations

from dataclasses import dataclass, replace

from voxshape.protocol import ACTION_NAMES
from voxshape.services.learner.config import LearnerConfig
from voxshape.services.learner.sarsa import Learner
from voxshape.services.learner.traces import TraceBook

FORWARD, LEFT = ACTION_NAMES.index("forward"), ACTION_NAMES.index("left")


@dataclass(frozen=True)
class P:
    """A crafted percept."""

    laser: tuple
    sonar: tuple = (1.0,) * 8
    goal_distance: float = 3.0
    goal_bearing: float = 0.0
    theta: float = 0.0
    reward: float = -1.0
    outcome: str = "running"
    step: int = 0
    x: float = 0.0
    y: float = 0.0
    collided: bool = False


WALL_LEFT = tuple([0.5] * 90 + [3.0] * 90)  # (beam 0 is on the right)
WALL_RIGHT = tuple([3.0] * 90 + [0.5] * 90)

EXACT = LearnerConfig(
    alpha=0.5,
    gamma=0.9,
    lam=0.8,
    blend=False,
    epsilon_start=0.0,
    epsilon_end=0.0,
    max_hold=1,
    clear_range=None,
    use_sonar=False,
    representation="pearson",  # Q's row i is state i, born as the readings come
    pearson_threshold=0.9,
    near_range=None,
    goal_sectors=0,
    potential="none",  # no guess: the update as the paper's, computed by hand
    lookahead_weight=0.0,
)


KEYS = replace(EXACT, goal_sectors=8, representation="keys")


def run_episode(learner: Learner, book: TraceBook, command_at: int | None = None) -> None:
    shapes = [WALL_LEFT, WALL_RIGHT, WALL_LEFT, WALL_RIGHT]
    for step, laser in enumerate(shapes):
        end = step == len(shapes) - 1
        p = P(laser, reward=50.0 if end else -1.0, outcome="goal" if end else "running", step=step)
        if step == command_at:
            learner.command("left")
        book.record(p, learner.step(p))

"""The potential Phi over the robot's place: how far along the way a place is, in metres.

The learner gets Phi as potential-based shaping, F = gamma^k Phi(s') - Phi(s) (Ng, Harada &
Russell 1999: it keeps the optimal policy), times `potential_scale`, and its policy looks
ahead along Phi (sarsa.py `_expected_progress`). The default is the straight line: Phi(x, y)
= -|(x, y) - goal|, the goal read from the observations' goal fields, so a robot nobody talks
to heads for its goal as the crow flies where its laser shows the way free, and learns where
the straight line is wrong. The experiments' oracle (voxshape/lab/experiment/oracle.py) is the
true shortest-path distance: the ceiling of what a potential over places could carry.

A potential learnt from the person's words (a model of what the person judges) was measured
and lost against this one: docs/decisions.md, 2026-11-29."""

from __future__ import annotations

import math
from typing import Protocol

Place = tuple[float, float]


class Potential(Protocol):
    """Phi over places, in metres (higher: further along the way)."""

    def value(self, x: float, y: float) -> float: ...


class StraightLine:
    """Minus the straight line to the goal; 0 until the goal is known."""

    def __init__(self, goal: Place | None = None) -> None:
        self.goal = goal

    def value(self, x: float, y: float) -> float:
        if self.goal is None:
            return 0.0
        return -math.hypot(x - self.goal[0], y - self.goal[1])

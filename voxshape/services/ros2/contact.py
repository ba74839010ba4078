"""When a real robot touches something: a bump, all round. Pure (times are robot seconds).

A bump is whichever comes first:
- the scan: its nearest reading in any direction under `radius` (from the robot's centre; a
  scan that does not look behind cannot see a bump there);
- odometry stuck: for `stuck_after` seconds of the robot's own clock (its odometry's stamps:
  a robot whose process stalls moves nothing in them either) it was told to move (at least
  `MOVING` m/s) and its odometry moved less than `progress` of the way the commands asked.
  This catches what the scan cannot: a radius no larger than the robot (it stops where its
  body touches, and no reading gets nearer), or a wall the scan does not see. A robot whose
  wheels slip against a wall keeps counting on its odometry: then only the scan tells.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Literal

import numpy as np

Why = Literal["scan", "stuck"]
MOVING = 0.02  # m/s: a command slower than this asks for no progress


@dataclass(frozen=True)
class ContactConfig:
    radius: float  # metres from the robot's centre: a scan reading nearer is a bump
    stuck_after: float = 0.5  # robot seconds of commands that moved (nearly) nothing
    progress: float = 0.25  # of the commanded distance, at least, or it is stuck


@dataclass(frozen=True)
class Sample:
    time: float  # robot seconds
    x: float
    y: float
    speed: float  # |v| commanded over the step that ended here, m/s


class Contact:
    """One episode's contact watch: `touching` at each step, `reset` at each start."""

    def __init__(self, config: ContactConfig) -> None:
        self.config = config
        self.samples: deque[Sample] = deque()

    def reset(self) -> None:
        self.samples.clear()

    def touching(
        self, around: np.ndarray, time: float, x: float, y: float, speed: float
    ) -> Why | None:
        """Whether the robot touches something after a step: `around` its scan's nearest
        readings all round, (x, y) its odometry, `speed` the |v| it was told over the step."""
        nearest = np.nanmin(around) if np.isfinite(around).any() else math.inf
        if nearest < self.config.radius:
            return "scan"
        return "stuck" if self._stuck(Sample(time, x, y, abs(speed))) else None

    def _stuck(self, now: Sample) -> bool:
        samples, window = self.samples, self.config.stuck_after
        if samples and now.time == samples[-1].time:
            return False  # the same odometry again: a step without a new one
        if samples and now.time < samples[-1].time:
            samples.clear()  # its clock went back (the robot restarted): start again
        samples.append(now)
        while len(samples) > 1 and now.time - samples[1].time >= window:
            samples.popleft()  # the oldest kept is the last at least `window` before now
        first = samples[0]
        if now.time - first.time < window - 1e-9:
            return False
        steps = list(samples)[1:]
        if any(s.speed < MOVING for s in steps):
            return False  # told to stand still for a moment: no progress was asked
        asked = sum(s.speed * (s.time - p.time) for p, s in zip(samples, steps, strict=False))
        moved = math.hypot(now.x - first.x, now.y - first.y)
        return moved < self.config.progress * asked

"""What a real robot may be told: safety first. Pure (times are given).

A command moves the robot only while everything it rests on is fresh: the learner's actions
(a command lapses `action_timeout` seconds after it was given: a dead learner, a lost bus),
the robot's own scan and odometry (`data_timeout`), the link to the session's router. When
any of them lapses, when an episode ends and on exit, the robot is told to stop: zero
velocity, sent at once and again for a few control periods (one zero lost on the way must not
leave it running), then nothing (so a person may drive it by hand while it waits). Speeds
beyond the limits are clipped, and counted. Times are wall seconds: safety is about the real
robot, whatever the time factor of a simulated one.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

ZEROS = 3  # control periods a stop is said


@dataclass(frozen=True)
class Limits:
    max_speed: float = 0.25  # m/s, forward and back
    max_turn: float = 1.5  # rad/s
    action_timeout: float = 0.4  # s a command stands without a new one
    data_timeout: float = 0.5  # s the robot's scan and odometry may be old

    def __post_init__(self) -> None:
        for name in ("max_speed", "max_turn", "action_timeout", "data_timeout"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name.replace('_', '-')} must be > 0, got {getattr(self, name)}")


Velocity = tuple[float, float]  # (v m/s, omega rad/s)
STOP: Velocity = (0.0, 0.0)


class Safety:
    def __init__(self, limits: Limits, period: float) -> None:
        self.limits = limits
        self.period = period  # wall seconds between repeated stops
        self.counters: Counter[str] = Counter()
        self.moving = False  # the last command sent was not a stop
        self.command: Velocity = STOP  # what the robot was last told
        self.given_at = -float("inf")  # when the standing command was given
        self.zeros_left = 0
        self.next_zero = 0.0
        self.why = "start"  # why it stopped last

    def clip(self, v: float, omega: float) -> Velocity:
        lim = self.limits
        cv = min(max(v, -lim.max_speed), lim.max_speed)
        co = min(max(omega, -lim.max_turn), lim.max_turn)
        if (cv, co) != (v, omega):
            self.counters["clipped"] += 1
        return cv, co

    def go(self, v: float, omega: float, now: float, fresh: bool) -> Velocity | None:
        """A command to send now, clipped; a stop instead when the robot's data or the bus is
        not `fresh`; None when there is nothing to send (already stopped and said so)."""
        if not fresh:
            return self.halt(now, "stale")
        velocity = self.clip(v, omega)
        if velocity == STOP:
            return self.halt(now, "asked")
        self.moving, self.given_at, self.command = True, now, velocity
        return velocity

    def halt(self, now: float, why: str) -> Velocity | None:
        """Stop now (unless stopped and said so for this reason already)."""
        if not self.moving and self.zeros_left and why == self.why:
            return None
        if self.moving or why != self.why:
            self.counters[f"stops.{why}"] += 1
        self.moving, self.why, self.command = False, why, STOP
        self.zeros_left, self.next_zero = ZEROS - 1, now + self.period
        return STOP

    def tick(self, now: float, fresh: bool) -> Velocity | None:
        """Each control period: the stop due, if any (a command lapsed, the data or the bus
        went stale, or a stop to repeat)."""
        if self.moving and not fresh:
            return self.halt(now, "stale")
        if self.moving and now - self.given_at > self.limits.action_timeout:
            return self.halt(now, "lapsed")
        if not self.moving and self.zeros_left and now >= self.next_zero:
            self.zeros_left -= 1
            self.next_zero = now + self.period
            return STOP
        return None

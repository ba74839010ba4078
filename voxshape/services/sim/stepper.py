"""The simulator service's core, without the bus: actions in, observations and episode events
out, in either clock mode.

- paced: the caller steps every control period of wall time (divided by the real-time
  factor); each robot moves with its latest action, and stops if it has none newer than
  `action_timeout` seconds.
- lockstep: the caller steps as soon as `ready()`: every robot has sent the action for its
  current step, or `action_timeout` passed (robots without one stop; counted and logged).
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from dataclasses import dataclass
from typing import Literal

from voxshape.protocol import Action, EpisodeEvent, Message, Observation
from voxshape.runtime import fields, worth_logging
from voxshape.services.sim.task import Reading, Simulation

Clock = Literal["paced", "lockstep"]
log = logging.getLogger("voxshape.services.sim")


@dataclass
class _Command:
    v: float
    omega: float
    step: int  # the observation step it answers
    received: float  # monotonic seconds


class Stepper:
    def __init__(
        self,
        sim: Simulation,
        clock: Clock,
        action_timeout: float,
        counters: Counter[str] | None = None,
    ) -> None:
        self.sim = sim
        self.clock = clock
        self.action_timeout = action_timeout
        self.counters: Counter[str] = Counter() if counters is None else counters
        self.current: dict[str, Reading] = {}  # the latest reading of each robot
        self.commands: dict[str, _Command] = {}
        self.waiting_since = time.monotonic()
        self.stalled: set[str] = set()  # paced: robots standing still for want of an action

    # -- inputs -----------------------------------------------------------------------------
    def start(self) -> list[Message]:
        """Starts every robot's first episode; the messages to publish."""
        self.current = self.sim.reset_all()
        self.waiting_since = time.monotonic()
        messages: list[Message] = []
        for reading in self.current.values():
            messages += [self._event(reading, "start"), observation(reading, time.time())]
        return messages

    def on_action(self, key_robot: str, action: Action) -> None:
        """Takes an action received on `key_robot`'s action key (or counts why not)."""
        if action.robot != key_robot:
            self._ignore(
                "robot_mismatch", action, f"says robot {action.robot!r} on {key_robot!r}'s key"
            )
            return
        if key_robot not in self.current:
            self._ignore("unknown_robot", action, "is for a robot this simulator does not run")
            return
        if action.v is None or action.omega is None:
            self._ignore("no_velocity", action, "has no (v, omega); the simulator needs them")
            return
        expected = self.current[key_robot].step
        if self.clock == "lockstep" and action.step != expected:
            kind = "late" if action.step < expected else "early"
            self._ignore(kind, action, f"answers step {action.step}, the robot is at {expected}")
            return
        v, omega, clipped = self.sim.config.model.clip(action.v, action.omega)
        if clipped:
            self.counters["clipped"] += 1
            if worth_logging(self.counters["clipped"]):
                log.warning(
                    "action clipped to the robot's limits",
                    extra=fields(
                        robot=key_robot, v=action.v, omega=action.omega, to=f"{v:.3f},{omega:.3f}"
                    ),
                )
        self.commands[key_robot] = _Command(v, omega, action.step, time.monotonic())

    def _ignore(self, why: str, action: Action, detail: str) -> None:
        self.counters[f"ignored.{why}"] += 1
        n = self.counters[f"ignored.{why}"]
        if worth_logging(n):
            log.warning(
                f"action ignored: it {detail}",
                extra=fields(reason=why, robot=action.robot, step=action.step, count=n),
            )

    # -- stepping -----------------------------------------------------------------------------
    def ready(self, now: float) -> bool:
        """Lockstep: every robot has its action for the current step, or the wait is over."""
        have = all(
            (c := self.commands.get(name)) is not None and c.step == reading.step
            for name, reading in self.current.items()
        )
        return have or now - self.waiting_since >= self.action_timeout

    def step(self, now: float) -> list[Message]:
        """One control step of every robot; the messages to publish."""
        velocities = {}
        for name, reading in self.current.items():
            c = self.commands.get(name)
            fresh = c is not None and (
                c.step == reading.step
                if self.clock == "lockstep"
                else now - c.received <= self.action_timeout
            )
            if fresh:
                velocities[name] = (c.v, c.omega)
                if name in self.stalled:
                    self.stalled.discard(name)
                    log.info("robot moving again", extra=fields(robot=name, step=reading.step))
            else:
                self._stop_without_action(name, reading.step, now)
        readings = self.sim.step(velocities)
        messages: list[Message] = []
        for name, reading in readings.items():
            messages.append(observation(reading, time.time()))
            if reading.outcome != "running":
                messages.append(self._event(reading, reading.outcome))
                reading = self.sim.reset(name)
                messages += [self._event(reading, "start"), observation(reading, time.time())]
            self.current[name] = reading
        self.counters["steps"] += 1
        self.waiting_since = now
        return messages

    def _stop_without_action(self, name: str, step: int, now: float) -> None:
        self.counters["stopped_without_action"] += 1
        if self.clock == "lockstep":  # every expired wait is worth a line (rate-limited)
            n = self.counters["stopped_without_action"]
            if worth_logging(n):
                log.warning(
                    "no action within the wait: robot stopped for this step",
                    extra=fields(
                        robot=name, step=step, count=n, waited=f"{now - self.waiting_since:.2f}s"
                    ),
                )
        elif name not in self.stalled:  # paced: standing still is normal, say when it starts
            self.stalled.add(name)
            log.info(
                "robot stands still: no action newer than the timeout",
                extra=fields(robot=name, step=step, timeout=f"{self.action_timeout}s"),
            )

    # -- messages -----------------------------------------------------------------------------
    def _event(self, r: Reading, kind: str) -> EpisodeEvent:
        return EpisodeEvent(
            robot=r.robot,
            episode=r.episode,
            step=r.step,
            kind=kind,
            episode_steps=r.episode_step,
            sim_time=r.sim_time,
            wall_time=time.time(),
            env_return=r.episode_return,
        )


def observation(r: Reading, wall_time: float, *, scans: bool = True) -> Observation:
    """The message of a simulator reading; without `scans`, laser and sonar are left empty
    (for readers that never look at them, e.g. the arbiter in in-process experiments)."""
    return Observation(
        robot=r.robot,
        episode=r.episode,
        step=r.step,
        episode_step=r.episode_step,
        sim_time=r.sim_time,
        wall_time=wall_time,
        x=r.pose.x,
        y=r.pose.y,
        theta=r.pose.theta,
        v=r.v,
        omega=r.omega,
        laser=tuple(r.laser.tolist()) if scans else (),
        sonar=tuple(r.sonar.tolist()) if scans else (),
        reward=r.reward,
        goal_distance=r.goal_distance,
        goal_bearing=r.goal_bearing,
        outcome=r.outcome,
        collided=r.collided,
    )

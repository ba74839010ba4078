"""Initial traces dictated by a simulated person (voxshape/services/simteacher/dictating.py): each
episode driven by the commands the person says, each held until the next one is heard,
recorded in a TraceBook for the learner to replay. What it cost the person is counted: the
robot seconds the dictation took and the words said."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from voxshape.protocol import ACTION_NAMES
from voxshape.protocol.vocabulary import load_vocabulary
from voxshape.services.learner.actions import ActionSet
from voxshape.services.learner.config import LearnerConfig
from voxshape.services.learner.traces import TraceBook
from voxshape.services.sim.task import SimConfig, Simulation
from voxshape.services.simteacher.dictating import TURNS, DictatingPerson, DictationProfile
from voxshape.world.maps import Map
from voxshape.world.robot import RobotModel

# A dictated episode pinned at a wall (this many bumps within PINNED_S seconds) stops: it is
# not the way.
PINNED_BUMPS, PINNED_S = 3, 10.0


ROBOT = RobotModel()
FRONT = np.abs(ROBOT.laser_angles()) < math.radians(30)  # the beams ahead of the robot
STOP_SHORT = 0.35  # metres from the laser: a robot driven forward stops short of a wall


def blocked_ahead(laser: Sequence[float]) -> bool:
    """Whether the laser shows something within STOP_SHORT straight ahead."""
    return bool(np.min(np.asarray(laser)[FRONT]) < STOP_SHORT)


@dataclass
class Dictation:
    book: TraceBook
    seconds: float  # robot seconds the dictated episodes took
    words: int  # commands the person said (misheard ones included)


def dictate(
    m: Map,
    episodes: int,
    seed: int = 100,
    sim_config: SimConfig | None = None,
    config: LearnerConfig | None = None,
    profile: DictationProfile | None = None,
) -> Dictation:
    """Episodes driven by the person's commands, each to the goal, its timeout or the robot
    pinned at a wall (a dictation that keeps meeting a wall stops: it is not the way), until
    `episodes` of them reached the goal or the person has tried twice as many and once more;
    with the actions of the learner `config` that will learn from them. Until the first word
    is heard the robot waits (steps recorded as the robot's own, which teach nothing)."""
    sim = Simulation(m, ("robot",), sim_config, seed=seed)
    config = config or LearnerConfig()
    actions = ActionSet(config)
    profile = profile or DictationProfile()
    person = DictatingPerson(m, load_vocabulary(), profile, config.velocities, seed=seed)
    book, seconds, period = TraceBook(), 0.0, sim.config.control_period
    try:
        shown = 0
        for _ in range(2 * episodes + 1):
            if shown == episodes:
                break
            reading = sim.reset("robot")
            start, doing, heard, turning = seconds, None, [], 0
            bumps, bumped = [], False  # when the last bumps were
            for _ in range(sim.max_episode_steps + 1):
                now = start + reading.episode_step * period
                while heard and heard[0].heard_at <= now:
                    doing = heard.pop(0).heard
                    turning = round(profile.turn_s / period) if doing in TURNS else 0
                if reading.collided and not bumped:
                    bumps = [t for t in bumps if t > now - PINNED_S] + [now]
                bumped = reading.collided
                if reading.collided:
                    doing, turning = None, 0  # a bump ends the held command: the robot waits
                carried = "forward" if doing in TURNS and not turning else doing
                if carried == "forward" and blocked_ahead(reading.laser):
                    doing = carried = None  # it stops short of a wall: the robot waits
                pose = reading.pose
                said = person.watch(now, pose.x, pose.y, pose.theta, reading.v, reading.omega,
                                    carried or "stop", reading.collided)  # fmt: skip
                if said is not None and said.heard is not None:
                    heard.append(said)
                if reading.outcome != "running" or len(bumps) >= PINNED_BUMPS:
                    book.record(reading, None)  # pinned at a wall: it stops, not the way
                    break
                decision = actions.one_hot(ACTION_NAMES.index(carried or "stop"), "teacher")
                if carried is None:
                    decision = actions.one_hot(ACTION_NAMES.index("stop"))
                turning = max(0, turning - 1)
                book.record(reading, decision)
                reading = sim.step({"robot": (decision.v, decision.omega)})["robot"]
            seconds = start + reading.episode_step * period
            shown += reading.outcome == "goal"
    finally:
        sim.close()
    return Dictation(book, seconds, person.words)

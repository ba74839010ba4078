"""Initial traces dictated by a simulated person (voxshape/services/simteacher/dictating.py): each
episode driven by the commands the person says, each held until the next one is heard,
recorded in a TraceBook for the learner to replay. What it cost the person is counted: the
robot seconds the dictation took and the words said."""

from __future__ import annotations

from dataclasses import dataclass

from voxshape.protocol import ACTION_NAMES
from voxshape.protocol.vocabulary import load_vocabulary
from voxshape.services.learner.actions import ActionSet
from voxshape.services.learner.config import LearnerConfig
from voxshape.services.learner.traces import TraceBook
from voxshape.services.sim.task import SimConfig, Simulation
from voxshape.services.simteacher.dictating import DictatingPerson, DictationProfile
from voxshape.world.maps import Map


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
    """`episodes` episodes driven by the person's commands, each to the goal or its timeout,
    with the actions of the learner `config` that will learn from them. Until the first word
    is heard the robot waits (steps recorded as the robot's own, which teach nothing)."""
    sim = Simulation(m, ("robot",), sim_config, seed=seed)
    config = config or LearnerConfig()
    actions = ActionSet(config)
    profile = profile or DictationProfile()
    person = DictatingPerson(m, load_vocabulary(), profile, config.velocities, seed=seed)
    book, seconds, period = TraceBook(), 0.0, sim.config.control_period
    try:
        for _ in range(episodes):
            reading = sim.reset("robot")
            start, doing, heard = seconds, None, []
            for _ in range(sim.max_episode_steps + 1):
                now = start + reading.episode_step * period
                while heard and heard[0].heard_at <= now:
                    doing = heard.pop(0).heard
                pose = reading.pose
                said = person.watch(now, pose.x, pose.y, pose.theta, reading.v, reading.omega,
                                    doing or "stop", reading.collided)  # fmt: skip
                if said is not None and said.heard is not None:
                    heard.append(said)
                if reading.outcome != "running":
                    book.record(reading, None)
                    break
                decision = (
                    actions.one_hot(ACTION_NAMES.index(doing), "teacher")
                    if doing
                    else actions.one_hot(ACTION_NAMES.index("stop"))
                )
                book.record(reading, decision)
                reading = sim.step({"robot": (decision.v, decision.omega)})["robot"]
            seconds = start + reading.episode_step * period
    finally:
        sim.close()
    return Dictation(book, seconds, person.words)

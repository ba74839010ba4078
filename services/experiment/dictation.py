"""Initial traces dictated by the simulated teacher: episodes it steers by commands alone, as a
person would ("forward" when facing the shortest path, else the turn towards it), recorded in
a TraceBook for the learner to replay."""

from __future__ import annotations

from services.learner.config import LearnerConfig
from services.learner.sarsa import Learner
from services.learner.traces import TraceBook
from services.sim.task import SimConfig, Simulation
from services.teacher.simulated.teacher import path_command
from services.world.maps import Map


def dictate(
    m: Map,
    episodes: int,
    seed: int = 100,
    sim_config: SimConfig | None = None,
    config: LearnerConfig | None = None,
) -> TraceBook:
    """`episodes` episodes driven by the teacher's commands, each to the goal or its timeout,
    with the actions (velocities, command steps) of the learner `config` that will learn
    from them."""
    sim = Simulation(m, ("robot",), sim_config, seed=seed)
    learner, book = Learner(config, seed=seed), TraceBook()
    try:
        for _ in range(episodes):
            reading = sim.reset("robot")
            for _ in range(sim.max_episode_steps + 1):
                pose = reading.pose
                learner.command(path_command(m, pose.x, pose.y, pose.theta))
                decision = learner.step(reading)
                book.record(reading, decision)
                if decision is None:
                    break
                reading = sim.step({"robot": (decision.v, decision.omega)})["robot"]
    finally:
        sim.close()
    return book

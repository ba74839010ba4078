"""What initial traces change: a scripted teacher that follows the map's shortest path dictates
a few episodes (commands only, as a person would), then SARSA(lambda) trains with those traces
replayed (before learning and every `replay_every` episodes) and without them.

    .venv/bin/python benchmarks/initial_traces.py --task 2 --traces 3 --seeds 3

The scripted teacher here is a stand-in until the simulated teacher (issue 8) exists.
"""

from __future__ import annotations

import argparse
import math

from services.learner.config import LearnerConfig
from services.learner.sarsa import Learner
from services.learner.traces import TraceBook
from services.learner.train import train
from services.sim.maps import Map, load_map
from services.sim.task import Simulation

BERTH = 0.45  # metres the scripted teacher keeps between the robot's centre and the walls


def downhill_heading(m: Map, x: float, y: float) -> float | None:
    """The direction of steepest descent of the geodesic distance to the goal, near (x, y)."""
    grid, distance = m.grid, m.grid.distances_to_goal(BERTH)
    row, col = grid.cell(x, y)
    best, best_distance = None, distance[row, col]
    for dr in (-2, -1, 0, 1, 2):
        for dc in (-2, -1, 0, 1, 2):
            r, c = row + dr, col + dc
            if 0 <= r < grid.rows and 0 <= c < grid.cols and distance[r, c] < best_distance:
                best, best_distance = (dr, dc), distance[r, c]
    return math.atan2(best[0], best[1]) if best else None


def dictate(task: str, episodes: int, seed: int = 100) -> TraceBook:
    """Episodes driven by spoken-style commands: forward when facing downhill, else turn."""
    m = load_map(task)
    sim, learner, book = Simulation(m, ("robot",), seed=seed), Learner(seed=seed), TraceBook()
    for _ in range(episodes):
        reading = sim.reset("robot")
        while True:
            heading = downhill_heading(m, reading.pose.x, reading.pose.y)
            error = (
                0.0 if heading is None else math.remainder(heading - reading.pose.theta, math.tau)
            )
            learner.command(
                "forward" if abs(error) < math.radians(20) else "left" if error > 0 else "right"
            )
            decision = learner.step(reading)
            book.record(reading, decision)
            if decision is None:
                break
            reading = sim.step({"robot": (decision.v, decision.omega)})["robot"]
        print(f"dictated trace: {reading.outcome} in {reading.episode_step} steps")
    sim.close()
    return book


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--task", default="2")
    parser.add_argument("--traces", type=int, default=3)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--max-episodes", type=int, default=300)
    args = parser.parse_args()
    book = dictate(args.task, args.traces)
    print("| traces | seed | converged | episodes | goals reached | states |")
    print("|---|---|---|---|---|---|")
    for traces in (book, None):
        for seed in range(args.seeds):
            r = train(args.task, seed, LearnerConfig(), args.max_episodes, traces=traces)
            goals = sum(e.outcome == "goal" for e in r.history)
            print(
                f"| {len(book.episodes) if traces else 0} | {seed} | {r.converged} | "
                f"{r.episodes} | {goals} | {r.states} |",
                flush=True,
            )


if __name__ == "__main__":
    main()

"""Initial traces: episodes a teacher steered, recorded, saved, and shown to the learner.

An episode in which the teacher gave at least one command is kept whole (the percepts, the
action taken at each step and who chose it). One that reached the goal is the way, shown to
the learner before its own episodes (words.py: votes all along it for the way on), so the
robot heads along it where it differs from its own guess. Its returns are not replayed
through the SARSA update: the shown actions would get their real, negative returns while the
untried ones kept their optimistic 0, and the robot would learn to avoid the way it was shown
(docs/decisions.md). Files are .npz arrays, no pickle.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from voxshape.services.learner.actions import N_ACTIONS, Decision
from voxshape.services.learner.sarsa import Learner, LearnerPercept

OUTCOMES = ("running", "goal", "collision", "timeout")


@dataclass(frozen=True)
class TracePercept:
    laser: np.ndarray
    sonar: np.ndarray
    goal_distance: float
    goal_bearing: float
    reward: float
    outcome: str
    step: int
    theta: float  # the pose: heading (goal sectors) and position (tiles)
    x: float
    y: float
    collided: bool = False


@dataclass
class TraceBook:
    """Recorded episodes: each a list of (percept, decision or None at the end)."""

    episodes: list[list[tuple[TracePercept, Decision | None]]] = field(default_factory=list)
    poses: bool = True  # False: read from a file saved before poses were kept
    _current: list[tuple[TracePercept, Decision | None]] = field(default_factory=list)

    def record(self, p: LearnerPercept, decision: Decision | None) -> None:
        """Call with every percept and the decision taken on it (None once it ended)."""
        self._current.append(
            (
                TracePercept(
                    np.asarray(p.laser, float),
                    np.asarray(p.sonar, float),
                    float(p.goal_distance),
                    float(p.goal_bearing),
                    float(p.reward),
                    p.outcome,
                    int(p.step),
                    float(p.theta),
                    float(p.x),
                    float(p.y),
                    bool(p.collided),
                ),
                decision,
            )
        )
        if decision is None:
            if any(d is not None and d.chooser == "teacher" for _, d in self._current):
                self.episodes.append(self._current)
            self._current = []

    def words(self, command_steps: int) -> int:
        """The commands a person says to dictate these episodes: a command lasts
        `command_steps` steps, so a run of L steps of one command takes ceil(L / that)."""
        said = 0
        for episode in self.episodes:
            run, previous = 0, None
            for _, decision in episode:
                command = decision.discrete if decision and decision.chooser == "teacher" else None
                if command != previous and run:
                    said += -(-run // command_steps)
                    run = 0
                run += command is not None
                previous = command
            said += -(-run // command_steps)
        return said

    def show(self, learner: Learner) -> int:
        """Shows the learner every recorded episode that reached the goal, as the way
        (words.py); returns how many. An episode that did not is not the way, nor one saved
        before positions were kept (it knows no place)."""
        if not self.poses:
            return 0
        shown = [e for e in self.episodes if e[-1][0].outcome == "goal"]
        for recorded in shown:
            learner.words.shown([(p.x, p.y, p.collided) for p, _ in recorded])
        return len(shown)

    def save(self, path: Path) -> None:
        rows = [(i, p, d) for i, ep in enumerate(self.episodes) for p, d in ep]
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(
            path,
            episode=np.array([i for i, _, _ in rows], dtype=np.int64),
            laser=np.array([p.laser for _, p, _ in rows]),
            sonar=np.array([p.sonar for _, p, _ in rows]),
            goal=np.array([(p.goal_distance, p.goal_bearing) for _, p, _ in rows]),
            reward=np.array([p.reward for _, p, _ in rows]),
            outcome=np.array([OUTCOMES.index(p.outcome) for _, p, _ in rows], dtype=np.int64),
            step=np.array([p.step for _, p, _ in rows], dtype=np.int64),
            pose=np.array([(p.x, p.y, p.theta) for _, p, _ in rows]).reshape(len(rows), 3),
            weights=np.array([d.weights if d else np.zeros(N_ACTIONS) for _, _, d in rows]),
            velocity=np.array([(d.v, d.omega) if d else (0.0, 0.0) for _, _, d in rows]),
            teacher=np.array([bool(d and d.chooser == "teacher") for _, _, d in rows]),
            collided=np.array([p.collided for _, p, _ in rows], dtype=bool),
            ended=np.array([d is None for _, _, d in rows]),
        )

    @classmethod
    def load(cls, path: Path) -> TraceBook:
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except (OSError, ValueError) as e:
            raise ValueError(f"{path}: not a trace file ({e})") from None
        n = len(data.get("episode", []))
        book = cls(poses="pose" in data)
        pose = data.get("pose", np.zeros((n, 3)))
        collided = data.get("collided", np.zeros(n, dtype=bool))
        if "theta" in data:  # saved with headings alone, before positions were kept
            pose[:, 2] = data["theta"]
        for i in np.unique(data["episode"]) if len(data.get("episode", [])) else []:
            rows = np.flatnonzero(data["episode"] == i)
            book.episodes.append(
                [
                    (
                        TracePercept(
                            data["laser"][r],
                            data["sonar"][r],
                            float(data["goal"][r][0]),
                            float(data["goal"][r][1]),
                            float(data["reward"][r]),
                            OUTCOMES[int(data["outcome"][r])],
                            int(data["step"][r]),
                            float(pose[r][2]),
                            float(pose[r][0]),
                            float(pose[r][1]),
                            bool(collided[r]),
                        ),
                        None
                        if data["ended"][r]
                        else Decision(
                            data["weights"][r],
                            float(data["velocity"][r][0]),
                            float(data["velocity"][r][1]),
                            "teacher" if data["teacher"][r] else "policy",
                        ),
                    )
                    for r in rows
                ]
            )
        return book

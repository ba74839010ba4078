"""What a person's words tell the learner: votes about the way (way.py), each credited to
what it is about.

- A judgement ("good", "bad"...) is about the motion of the stretch it judges: the robot's
  displacement over the `judged_s` up to each step the arbiter credits (its delay-corrected
  guess of what the person saw), weighted by the arbiter's weight. "good" votes for that
  direction, "bad" against it, only where the guess judged the motion otherwise (a word that
  agrees with the guess tells it nothing new) and only if the robot moved: stuck or bumping
  is bad whatever the way, so a judgement of it says nothing of where the way goes.
- A command ("left", "right", "forward", "back") is about the heading the person wanted when
  deciding it: `command_turn` degrees aside of the robot's heading then (ahead, behind).
- A way shown whole, a dictated trace that reached the goal, votes all along it for the way
  on (towards the place TRACE_CHORD_M further, so its wobbles even out), but for the second
  before each bump.

The robot's poses of the last `feedback_window_s` are kept to credit late words; a word
about a step older than that is dropped (counted).
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Sequence

import numpy as np

from voxshape.services.learner.config import LearnerConfig
from voxshape.services.learner.way import Way
from voxshape.world.robot import CONTROL_PERIOD_S

TRACE_VOTE_M = 0.5  # metres of a shown way between its votes
TRACE_CHORD_M = 2.0  # metres further along it that each vote points to

Pose = tuple[float, float, float]  # x, y, heading


class WordCredit:
    def __init__(self, config: LearnerConfig, way: Way, counters: Counter[str]) -> None:
        self.config, self.way, self.counters = config, way, counters
        steps = max(1, round(config.feedback_window_s / CONTROL_PERIOD_S))
        # (step, x, y, heading, bumped, episode) of each step seen, in order
        self.trail: deque[tuple[int, float, float, float, bool, int]] = deque(maxlen=steps)

    def saw(self, step: int, pose: Pose, bumped: bool, episode: int = 0) -> None:
        """The robot at observation `step` of `episode` (each step, in order)."""
        self.trail.append((step, *pose, bumped, episode))

    def judged(self, step: int, weight: float, f: float) -> bool:
        """A judgement f credited to observation `step` with the arbiter's weight; False
        (counted) if that step has left the window."""
        end = self._entry_at(step)
        if end is None:
            return False
        first = step - round(self.config.judged_s / CONTROL_PERIOD_S)
        start = next(e for e in self.trail if e[0] >= first and e[5] == end[5])  # its episode's
        end, start = end[1:4], start[1:4]
        move = np.subtract(end[:2], start[:2])
        length = float(np.hypot(*move))
        vote = weight * math.copysign(1.0, f) if f else 0.0
        rise = self.way.phi(end[:2]) - self.way.phi(start[:2])
        if length < self.config.min_judged_move or self._bumped(first, step):
            self.counters["votes_stuck"] += 1  # stuck or bumping is bad any way round
        elif rise * vote > 0:
            self.counters["votes_agreeing"] += 1  # the guess judged it so too
        elif vote:
            middle = ((start[0] + end[0]) / 2, (start[1] + end[1]) / 2)
            self.way.vote(middle, move / length, vote)
            self.counters["votes_judged"] += 1
        self.counters["feedback_credited"] += 1
        return True

    def commanded(self, action: str, credits: Sequence[tuple[int, float]]) -> list[int]:
        """A command, about the steps the person saw when deciding it (with their weights);
        returns the steps that had left the window."""
        dropped = []
        for step, weight in credits:
            pose = self.pose_at(step)
            if pose is None:
                dropped.append(step)
            else:
                self._vote_heading(pose, action, weight)
        return dropped

    def answered(self, step: int, action: str) -> bool:
        """The answer to "which way?" asked at observation `step`: a command about the pose
        asked from; False if that step has left the window."""
        pose = self.pose_at(step)
        if pose is not None:
            self._vote_heading(pose, action, 1.0)
            self.counters["answers"] += 1
        return pose is not None

    def shown(self, path: Sequence[tuple[float, float, bool]]) -> None:
        """A way shown whole: its places and whether the robot bumped there."""
        places = np.array([p[:2] for p in path], dtype=float)
        along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(places, axis=0).T))])
        before_bump = np.zeros(len(path), dtype=bool)
        for i in (i for i, p in enumerate(path) if p[2]):
            before_bump[max(0, i - round(1 / CONTROL_PERIOD_S)) : i + 1] = True
        for metre in np.arange(0.0, along[-1], TRACE_VOTE_M):
            i = int(np.searchsorted(along, metre))
            j = min(int(np.searchsorted(along, metre + TRACE_CHORD_M)), len(path) - 1)
            move = places[j] - places[i]
            length = float(np.hypot(*move))
            if length > 0.1 and not before_bump[i : j + 1].any():
                self.way.vote(tuple(places[i]), move / length, 1.0)
                self.counters["votes_shown"] += 1

    def pose_at(self, step: int) -> Pose | None:
        """The robot's pose at observation `step` (the latest before it), if still kept."""
        entry = self._entry_at(step)
        return None if entry is None else entry[1:4]

    def _entry_at(self, step: int) -> tuple[int, float, float, float, bool, int] | None:
        if not self.trail or step < self.trail[0][0]:
            return None
        return next((e for e in reversed(self.trail) if e[0] <= step), None)

    def _bumped(self, first: int, last: int) -> bool:
        return any(e[4] for e in self.trail if first <= e[0] <= last)

    def _vote_heading(self, pose: Pose, action: str, weight: float) -> None:
        """A command's vote: the way lies where it turns the robot from the pose the person
        saw (ahead for "forward", behind for "back", `command_turn` degrees for a turn)."""
        turn = math.radians(self.config.command_turn)
        aside = {"forward": 0.0, "left": turn, "right": -turn, "back": math.pi}.get(action)
        if aside is None:  # "stop" says nothing of where the way goes
            return
        heading = pose[2] + aside
        self.way.vote(pose[:2], np.array([math.cos(heading), math.sin(heading)]), weight)
        self.counters["votes_commanded"] += 1

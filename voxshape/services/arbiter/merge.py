"""Several teachers, one robot: merging their judgements, and how often they agree.

Policies (judgements "about the same steps" have credited step ranges within `slack` steps):
- sum (default): each judgement goes to the learner at once, its reward times the teacher's
  weight; the learner adds them up, so opposite judgements on the same steps cancel out.
- mean: judgements are held for `window` seconds after the first; those about the same
  steps become one feedback with the weighted mean reward and the weighted mean credits.
- majority: like mean, but only the side (positive or negative) with the greater total teacher
  weight counts; a tie sends nothing (counted as `conflict_tie`).
The merged reward goes to the learner as it is: the bound g is the learner's (`credit` clips f
to `feedback_bound`).
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass

from voxshape.services.arbiter.config import MergePolicy

MAX_BATCH = 64  # judgements held for one robot: more close the batch early


@dataclass(frozen=True)
class Judgement:
    """One understood qualifier or goal, credited."""

    robot: str
    teacher: str
    source: str  # the utterance's message id
    reward: float  # from the vocabulary
    weight: float  # the teacher's weight
    credits: tuple[tuple[int, float], ...]  # (step, weight), summing to 1
    arrived: float  # arbiter clock

    @property
    def steps(self) -> tuple[int, int]:
        return self.credits[0][0], self.credits[-1][0]

    def near(self, other: Judgement, slack: int) -> bool:
        """About the same steps: credited step ranges within `slack` steps of each other."""
        (a0, a1), (b0, b1) = self.steps, other.steps
        return a0 - slack <= b1 and b0 - slack <= a1


@dataclass(frozen=True)
class Merged:
    """What goes to the learner: a reward (before the bound g) credited to steps."""

    robot: str
    reward: float
    credits: tuple[tuple[int, float], ...]
    sources: tuple[str, ...]
    teachers: tuple[str, ...]


def _sign(x: float) -> int:
    return (x > 0) - (x < 0)


class Merger:
    def __init__(self, policy: MergePolicy, window: float, slack: int) -> None:
        self.policy, self.window, self.slack = policy, window, slack
        self.counters: Counter[str] = Counter()
        self._batches: dict[str, list[Judgement]] = {}

    def add(self, judgement: Judgement) -> list[Merged]:
        """Feedback to send now: at once with `sum`, else when the batch is due."""
        if judgement.weight <= 0:
            self.counters["muted_teacher"] += 1
            return []
        if self.policy == "sum":
            return [_combine([judgement], sum_rewards=True)]
        batch = self._batches.setdefault(judgement.robot, [])
        batch.append(judgement)
        if len(batch) >= MAX_BATCH:
            return self._resolve(self._batches.pop(judgement.robot))
        return []

    def due(self, now: float) -> list[Merged]:
        """Feedback of the batches whose window has passed."""
        ready = [r for r, b in self._batches.items() if now - b[0].arrived >= self.window]
        return [m for robot in ready for m in self._resolve(self._batches.pop(robot))]

    def flush(self) -> list[Merged]:
        return [m for robot in list(self._batches) for m in self._resolve(self._batches.pop(robot))]

    @property
    def held(self) -> int:
        return sum(len(b) for b in self._batches.values())

    def _resolve(self, batch: list[Judgement]) -> list[Merged]:
        merged = []
        for group in _groups(batch, self.slack):
            if len({j.teacher for j in group}) > 1 and len({_sign(j.reward) for j in group}) > 1:
                self.counters["conflicts"] += 1
            if self.policy == "majority":
                score = sum(j.weight * _sign(j.reward) for j in group)
                if score == 0:
                    self.counters["conflict_tie"] += 1
                    continue
                group = [j for j in group if _sign(j.reward) == _sign(score)]
            merged.append(_combine(group, sum_rewards=False))
        return merged


def _groups(batch: list[Judgement], slack: int) -> list[list[Judgement]]:
    """Judgements linked by being about the same steps (single linkage), in arrival order."""
    groups: list[list[Judgement]] = []
    for j in batch:
        linked = [g for g in groups if any(j.near(k, slack) for k in g)]
        for g in linked:
            groups.remove(g)
        groups.append([k for g in linked for k in g] + [j])
    return groups


def _combine(group: list[Judgement], sum_rewards: bool) -> Merged:
    total_weight = sum(j.weight for j in group)
    reward = sum(j.weight * j.reward for j in group)
    credits: dict[int, float] = {}
    for j in group:
        for step, w in j.credits:
            credits[step] = credits.get(step, 0.0) + w * j.weight / total_weight
    return Merged(
        robot=group[0].robot,
        reward=reward if sum_rewards else reward / total_weight,
        credits=tuple(sorted(credits.items())),
        sources=tuple(j.source for j in group),
        teachers=tuple(dict.fromkeys(j.teacher for j in group)),
    )


class Agreement:
    """How often each teacher agrees with the others: every pair of judgements by two teachers
    about the same steps of a robot, within `horizon` seconds, is one comparison for each;
    they agree when their rewards have the same sign."""

    def __init__(self, slack: int, horizon: float = 10.0, keep: int = 64) -> None:
        self.slack, self.horizon, self.keep = slack, horizon, keep
        self._recent: dict[str, deque[Judgement]] = {}  # per robot
        self.compared: Counter[tuple[str, str]] = Counter()  # (robot, teacher)
        self.agreed: Counter[tuple[str, str]] = Counter()

    def add(self, j: Judgement) -> None:
        recent = self._recent.setdefault(j.robot, deque(maxlen=self.keep))
        for k in recent:
            if (
                k.teacher != j.teacher
                and j.arrived - k.arrived <= self.horizon
                and j.near(k, self.slack)
            ):
                same = _sign(j.reward) == _sign(k.reward)
                for teacher in (j.teacher, k.teacher):
                    self.compared[j.robot, teacher] += 1
                    self.agreed[j.robot, teacher] += same
        recent.append(j)

    def share(self, robot: str, teacher: str) -> float | None:
        n = self.compared[robot, teacher]
        return self.agreed[robot, teacher] / n if n else None

"""Planning over a learned model: Dyna-Q with prioritized sweeping (Sutton & Barto, sections
8.2 and 8.4; Moore & Atkeson 1993).

The model counts what the robot's own decisions did: for each state s and action a taken
there, how often (n), the returns G the action earned while it was held, and the states s'
it led to, each with the sum of the discounts gamma^k of getting there (k steps held); a
terminal s' (the goal) has no future. Its expected backup of (s, a) is

    Q(s, a) <- [sum G + sum_s' sum gamma^k (Phi(s') + V(s'))] / n - Phi(s)

on the task's reward plus the teacher's potential (F = gamma^k Phi(s') - Phi(s)), with V(s')
the value of the best action already tried in s': an untried action's optimistic start is
not spread upstream (a key stands for many places, so untried pairs are everywhere).

Prioritized sweeping: a pair whose backup would move its Q by more than `threshold` waits
in a queue, the largest change first; each backup queues the pairs that lead into its state.
So the goal's value, or a word that moved the potential, reaches every state upstream of it
in a few dozen backups rather than one trace at a time.
"""

from __future__ import annotations

import heapq
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

END = -1  # the next state of a terminal transition: no future


@dataclass
class Outcomes:
    """What one action did in one state, summed over the times it was taken."""

    n: int = 0
    returns: float = 0.0  # sum of G (R_RL, and h's bonus with additive shaping)
    taught: float = 0.0  # sum of the teacher's rewards credited to it (g's f, additive)
    next: dict[int, list[float]] = field(default_factory=dict)  # s' -> [count, sum gamma^k]


class Model:
    """The robot's own transitions between decisions, counted."""

    def __init__(self) -> None:
        self.outcomes: dict[tuple[int, int], Outcomes] = {}
        self.into: defaultdict[int, set[tuple[int, int]]] = defaultdict(set)  # s' -> (s, a)
        self.tried: defaultdict[int, set[int]] = defaultdict(set)  # s -> actions taken there

    def __len__(self) -> int:
        return len(self.outcomes)

    def add(self, s: int, a: int, G: float, discount: float, s_next: int | None) -> None:
        """One decision: a taken in s earned G over k steps (discount = gamma^k) and led to
        s_next (None: a terminal state)."""
        o = self.outcomes.setdefault((s, a), Outcomes())
        o.n += 1
        o.returns += G
        target = END if s_next is None else s_next
        seen = o.next.setdefault(target, [0.0, 0.0])
        seen[0] += 1
        seen[1] += discount
        self.tried[s].add(a)
        if s_next is not None:
            self.into[s_next].add((s, a))

    def teach(self, s: int, a: int, f: float) -> bool:
        """The teacher's reward f credited to a taken in s: it becomes part of the pair's
        mean return (the paper's r <- g(r, f)); False if the pair has no outcome yet."""
        o = self.outcomes.get((s, a))
        if o is None:
            o = self.outcomes[(s, a)] = Outcomes()
        o.taught += f
        return o.n > 0

    def expected(self, s: int, a: int, future: Callable[[int], float]) -> float:
        """E[G + gamma^k future(s')] of a taken in s (future(s'): what s' is worth)."""
        o = self.outcomes[(s, a)]
        total = o.returns + o.taught
        for s_next, (_, discounts) in o.next.items():
            if s_next != END:
                total += discounts * future(s_next)
        return total / o.n

    def rows(self) -> tuple[np.ndarray, np.ndarray]:
        """The model as arrays, for a checkpoint: (s, a, n, returns) per pair and
        (s, a, s', count, sum of discounts) per transition."""
        pairs = [(s, a, o.n, o.returns, o.taught) for (s, a), o in self.outcomes.items()]
        moves = [
            (s, a, s2, count, discounts)
            for (s, a), o in self.outcomes.items()
            for s2, (count, discounts) in o.next.items()
        ]
        return np.array(pairs, dtype=float).reshape(-1, 5), np.array(moves).reshape(-1, 5)

    @classmethod
    def from_rows(cls, pairs: np.ndarray, moves: np.ndarray) -> Model:
        model = cls()
        for s, a, n, returns, taught in pairs:
            model.outcomes[(int(s), int(a))] = Outcomes(int(n), float(returns), float(taught))
            model.tried[int(s)].add(int(a))
        for s, a, s_next, count, discounts in moves:
            s, a, s_next = int(s), int(a), int(s_next)
            model.outcomes[(s, a)].next[s_next] = [float(count), float(discounts)]
            if s_next != END:
                model.into[s_next].add((s, a))
        return model


class Sweeper:
    """Prioritized sweeping over a model: `backup(s, a)` is the pair's new Q, `value(s, a)`
    its Q now, `assign(s, a, q)` sets it."""

    def __init__(self, model: Model, threshold: float) -> None:
        self.model, self.threshold = model, threshold
        self.queue: list[tuple[float, int, int]] = []  # (-priority, s, a)
        self.queued: dict[tuple[int, int], float] = {}  # the latest priority of each pair
        self.backups = 0

    def consider(self, s: int, a: int, change: float) -> None:
        """Queues (s, a) if its backup would change its Q by more than the threshold."""
        priority = abs(change)
        if priority > self.threshold and priority > self.queued.get((s, a), 0.0):
            self.queued[(s, a)] = priority
            heapq.heappush(self.queue, (-priority, s, a))

    def sweep(
        self,
        steps: int,
        backup: Callable[[int, int], float],
        value: Callable[[int, int], float],
        assign: Callable[[int, int, float], None],
    ) -> int:
        """Up to `steps` backups, the largest change first; returns how many were made."""
        done = 0
        while self.queue and done < steps:
            negative, s, a = heapq.heappop(self.queue)
            if self.queued.get((s, a)) != -negative:
                continue  # a stale entry: the pair was queued again with another priority
            del self.queued[(s, a)]
            assign(s, a, backup(s, a))
            done += 1
            for p, b in self.model.into.get(s, ()):
                self.consider(p, b, backup(p, b) - value(p, b))
        self.backups += done
        return done

    def clear(self) -> None:
        self.queue.clear()
        self.queued.clear()

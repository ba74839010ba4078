"""Delay correction: which steps an utterance is about, on the simulator's clock.

Step k is displayed from its observation's wall_time until the next observation's: the action
chosen at step k is what the teacher watches then, so a judgement is credited to step ids (the
learner finds the decision containing each). A teacher who starts speaking at `onset` judged
what they saw `delay` seconds earlier; with a window [lo, hi] of delays, the steps displayed
within [onset - hi, onset - lo] are credited, each weighted by how long it was displayed in
that window (weights sum to 1). Terminal steps (no action was chosen) are never credited.

The window is TAMER's 0.2-0.8 s (or a teacher's own setting) until the teacher's reaction
delay has been learnt from their reactions to salient events with known times: a bump
(`Observation.collided`, first of a run) or the goal (`outcome == "goal"`). Judgements of the
matching sign (negative after a bump, positive or "goal" after the goal) within a few seconds
are candidate reactions (ReactionDelay finds the delay they agree on). Delays are measured from
the middle of the display interval of the step that led to the event, so a window centred on
the learnt delay credits that step: the teacher's reaction time, the display's latency and any
constant clock error are all absorbed in it.
"""

from __future__ import annotations

import statistics
from bisect import bisect_left, bisect_right
from collections import Counter, OrderedDict, deque
from collections.abc import Hashable
from dataclasses import dataclass
from typing import Literal

from voxshape.protocol import Observation
from voxshape.services.arbiter.config import DelayLearning, DelayWindow

MAX_CREDITS = 256  # CreditedFeedback.credits holds at most this many
MIN_SHARE = 1e-3  # credits lighter than this share of the window are dropped


@dataclass(frozen=True)
class Spread:
    """An utterance's credit: (step, weight) with weights summing to 1."""

    credits: tuple[tuple[int, float], ...]
    episode: int  # the episode of the heaviest credit
    clamped: bool  # the window lay after the latest step: all on the latest step

    @property
    def centre(self) -> float:
        """The weighted mean step."""
        return sum(step * weight for step, weight in self.credits)


Added = Literal["next", "late", "restart"]  # what a step added to a timeline was


class StepTimeline:
    """One robot's recent steps on the simulator's clock (bounded in time and in count)."""

    def __init__(self, history_seconds: float = 30.0, max_steps: int = 20_000) -> None:
        self.history_seconds = history_seconds
        self.max_steps = max_steps
        self._steps: list[int] = []
        self._times: list[float] = []
        self._episodes: list[int] = []
        self._running: list[bool] = []
        self._head = 0  # entries before it are forgotten (compacted now and then)
        self._periods: deque[float] = deque(maxlen=16)
        self._paces: deque[float] = deque(maxlen=16)
        self._last_sim_time: float | None = None

    def __len__(self) -> int:
        return len(self._steps) - self._head

    def add(
        self,
        step: int,
        wall_time: float,
        episode: int,
        running: bool,
        sim_time: float | None = None,
    ) -> Added:
        """Appends a step ("next"), or starts the history over from it if it contradicts it (a
        restarted simulator, or a clock set back: "restart"). A step older in both number and
        time (recovered after a restart, behind live ones) goes in its place ("late")."""
        if self and step <= self._steps[-1] and wall_time <= self._times[-1]:
            return self._insert(step, wall_time, episode, running)
        in_order = not self or (step > self._steps[-1] and wall_time >= self._times[-1])
        if not in_order:
            self.clear()
        elif self and self._running[-1]:
            self._periods.append(wall_time - self._times[-1])
            last_sim = self._last_sim_time
            if sim_time is not None and last_sim is not None and sim_time > last_sim:
                self._paces.append((wall_time - self._times[-1]) / (sim_time - last_sim))
        self._last_sim_time = sim_time
        self._steps.append(step)
        self._times.append(wall_time)
        self._episodes.append(episode)
        self._running.append(running)
        self._forget_old(wall_time)
        return "next" if in_order else "restart"

    def _insert(self, step: int, wall_time: float, episode: int, running: bool) -> Added:
        """A late step between the remembered ones (or a copy of one), unless its time is out
        of order with its neighbours' (another run of the simulator)."""
        n, head = len(self._steps), self._head
        i = bisect_left(self._steps, step, head, n)
        if i < n and self._steps[i] == step:
            return "late"  # a copy
        after_previous = i == head or self._times[i - 1] <= wall_time
        if not (after_previous and wall_time <= self._times[i]):
            self.clear()
            self.add(step, wall_time, episode, running)
            return "restart"
        if wall_time < self._times[-1] - self.history_seconds:
            return "late"  # older than what is remembered
        for column, value in zip(
            (self._steps, self._times, self._episodes, self._running),
            (step, wall_time, episode, running),
            strict=True,
        ):
            column.insert(i, value)
        return "late"

    def clear(self) -> None:
        for column in (self._steps, self._times, self._episodes, self._running):
            column.clear()
        self._head = 0
        self._periods.clear()
        self._paces.clear()
        self._last_sim_time = None

    def _forget_old(self, now: float) -> None:
        n = len(self._steps)
        while self._head < n - 1 and (
            self._times[self._head] < now - self.history_seconds or n - self._head > self.max_steps
        ):
            self._head += 1
        if self._head > 1024 and self._head * 2 > n:
            for column in (self._steps, self._times, self._episodes, self._running):
                del column[: self._head]
            self._head = 0

    @property
    def latest_step(self) -> int | None:
        return self._steps[-1] if self else None

    @property
    def latest_episode(self) -> int | None:
        return self._episodes[-1] if self else None

    @property
    def period(self) -> float:
        """The typical display time of a step (median of the recent ones; 0.1 s before any)."""
        return statistics.median(self._periods) if self._periods else 0.1

    @property
    def pace(self) -> float:
        """Wall seconds per robot second (median of the recent steps; 1 before any): 0.05 on
        a simulator running at 20x real time."""
        return statistics.median(self._paces) if self._paces else 1.0

    def latest_running_step(self, before: float | None = None) -> tuple[int, int] | None:
        """(step, episode) of the latest step an action was chosen at (displayed before
        `before`, if given)."""
        end = len(self._steps) if before is None else bisect_right(self._times, before, self._head)
        for i in range(end - 1, self._head - 1, -1):
            if self._running[i]:
                return self._steps[i], self._episodes[i]
        return None

    def spread(self, start: float, end: float) -> Spread | None:
        """The steps displayed within [start, end], weighted by overlap; None if the window
        ends before the remembered history (too late to credit)."""
        n, head = len(self._steps), self._head
        if n == head or end <= self._times[head]:
            return None
        last_end = self._times[-1] + self.period
        if start >= last_end:
            return self._on_latest(clamped=True)
        i = max(head, bisect_right(self._times, start, head, n) - 1)
        overlaps: list[tuple[int, float, int]] = []
        while i < n and self._times[i] < end:
            shown_until = self._times[i + 1] if i + 1 < n else last_end
            overlap = min(shown_until, end) - max(self._times[i], start)
            if overlap > 0 and self._running[i]:
                overlaps.append((self._steps[i], overlap, self._episodes[i]))
            i += 1
        if not overlaps:
            return self._on_latest(clamped=True, before=end)
        total = sum(o for _, o, _ in overlaps)
        kept = [x for x in overlaps if x[1] >= MIN_SHARE * total]
        if len(kept) > MAX_CREDITS:
            kept = sorted(sorted(kept, key=lambda x: -x[1])[:MAX_CREDITS])
        total = sum(o for _, o, _ in kept)
        heaviest = max(kept, key=lambda x: x[1])
        credits = tuple((step, overlap / total) for step, overlap, _ in kept)
        return Spread(credits, heaviest[2], clamped=False)

    def _on_latest(self, clamped: bool, before: float | None = None) -> Spread | None:
        latest = self.latest_running_step(before)
        if latest is None:
            return None
        return Spread(((latest[0], 1.0),), latest[1], clamped)


@dataclass(frozen=True)
class SalientEvent:
    """Something a teacher reacts to at a known time: a bump (-1) or the goal (+1)."""

    step: int  # the step whose action led to it
    polarity: int
    seen_at: float  # simulator clock: the observation showing it
    reference: float  # simulator clock: the middle of `step`'s display interval


@dataclass(frozen=True)
class _Seen:
    step: int
    episode: int
    wall_time: float
    collided: bool
    running: bool


class SalientEvents:
    """One robot's recent salient events, detected from its observations."""

    def __init__(self, keep: int = 64) -> None:
        self._events: deque[SalientEvent] = deque(maxlen=keep)
        self._last: _Seen | None = None

    def observe(self, obs: Observation) -> SalientEvent | None:
        last = self._last
        self._last = _Seen(
            obs.step, obs.episode, obs.wall_time, obs.collided, obs.outcome == "running"
        )
        if last is None or not last.running or last.step != obs.step - 1:
            return None  # a new episode, or a gap: no known step led here
        if obs.outcome == "goal":
            polarity = 1
        elif obs.collided and not last.collided:
            polarity = -1
        else:
            return None
        event = SalientEvent(
            last.step, polarity, obs.wall_time, (last.wall_time + obs.wall_time) / 2
        )
        self._events.append(event)
        return event

    def seen_within(self, polarity: int, start: float, end: float) -> list[SalientEvent]:
        return [e for e in self._events if e.polarity == polarity and start <= e.seen_at <= end]

    def clear(self) -> None:
        self._events.clear()
        self._last = None


class ReactionDelay:
    """One teacher's reaction-delay window: configured until learnt from their reactions.

    For each recent salient event, every judgement of the matching sign that began within
    `pair_within` seconds after it is a candidate reaction, at delay = onset - the event's
    reference. A teacher who reacts to events does so at about the same delay each time, while
    their other judgements fall at random delays: the delay is where the candidates of the most
    events gather (within +-`tolerance`), learnt once `min_samples` events agree. The window is
    centred on the median of those agreeing delays, its half-width their spread (1.4826 MAD,
    the standard deviation of a normal), at least `min_half_width`. Only the latest `samples`
    events count, so a teacher whose timing changes is followed."""

    MAX_CANDIDATES = 8  # per event

    def __init__(self, configured: DelayWindow, learning: DelayLearning) -> None:
        self.configured = configured
        self.learning = learning
        self._candidates: OrderedDict[Hashable, list[float]] = OrderedDict()
        self._agreeing: list[float] | None = None  # cached consensus; None: to recompute

    def add(self, event: Hashable, delay: float) -> bool:
        """A judgement that may be a reaction to `event`, `delay` seconds after it."""
        if not 0.0 <= delay <= self.learning.pair_within + 1.0:
            return False
        candidates = self._candidates.setdefault(event, [])
        if len(candidates) >= self.MAX_CANDIDATES:
            return False
        candidates.append(delay)
        while len(self._candidates) > self.learning.samples:
            self._candidates.popitem(last=False)
        self._agreeing = None
        return True

    @property
    def agreeing(self) -> list[float]:
        """One delay per event, of the events that agree on the teacher's delay."""
        if self._agreeing is None:
            self._agreeing = self._consensus()
        return self._agreeing

    @property
    def learned(self) -> bool:
        return self.learning.enabled and len(self.agreeing) >= self.learning.min_samples

    def window(self) -> DelayWindow:
        if not self.learned:
            return self.configured
        delays = self.agreeing
        centre = statistics.median(delays)
        mad = statistics.median(abs(d - centre) for d in delays)
        half = min(max(1.4826 * mad, self.learning.min_half_width), self.learning.max_half_width)
        return DelayWindow(max(0.0, centre - half), centre + half)

    def _consensus(self) -> list[float]:
        """The densest +-tolerance range of candidate delays, counted in distinct events
        (a sliding window over the sorted candidates), then re-centred once on its median."""
        tolerance = self.learning.tolerance
        points = sorted(
            (d, event) for event, (_, ds) in enumerate(self._candidates.items()) for d in ds
        )
        if not points:
            return []
        inside: Counter[int] = Counter()
        best, best_range, left = 0, (points[0][0], points[0][0]), 0
        for d, event in points:
            inside[event] += 1
            while d - points[left][0] > 2 * tolerance:
                gone = points[left][1]
                inside[gone] -= 1
                if not inside[gone]:
                    del inside[gone]
                left += 1
            if len(inside) > best:
                best, best_range = len(inside), (points[left][0], d)
        centre = statistics.median(d for d, _ in points if best_range[0] <= d <= best_range[1])
        nearest: dict[int, float] = {}
        for d, event in points:
            if abs(d - centre) <= tolerance and (
                event not in nearest or abs(d - centre) < abs(nearest[event] - centre)
            ):
                nearest[event] = d
        return list(nearest.values())

"""The benchmarks' bus node: what a session's robots, teachers and services did, and when.

A `Probe` runs a bus node of the harness in a thread. It follows which nodes are present and
notes on the wall clock every observation and action, every word said, utterance, notice and
credited feedback of the session. The fleet (benchmarks/fleet) takes a point's `window()` of
it; the chaos and soak harness (benchmarks/harness) its `latencies()` and what it saw of the
words, beside the event log.
"""

from __future__ import annotations

import threading
import time
from collections import defaultdict
from dataclasses import dataclass, field

from benchmarks.common import percentile
from voxshape.protocol import (
    Action,
    CreditedFeedback,
    Observation,
    Said,
    TeacherNotice,
    Utterance,
)
from voxshape.runtime import BusConfig, Input, Node, Presence

KEEP_OBS = 20_000  # (robot, step) arrivals kept to match actions to their observations


@dataclass
class Seen:
    """Everything the probe saw, each at its arrival (wall clock, seconds)."""

    obs: dict[str, list[tuple[float, int, float]]] = field(
        default_factory=lambda: defaultdict(list)
    )  # robot -> (arrival, step, the simulator's wall time)
    obs_at: dict[tuple[str, int], float] = field(default_factory=dict)  # (robot, step)
    action_lag: list[tuple[float, float]] = field(default_factory=list)  # (at, obs -> action)
    actions: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    said: dict[str, tuple[float, str, str]] = field(default_factory=dict)  # sent, who, robot
    utterances: dict[str, tuple[float, Utterance]] = field(default_factory=dict)
    notices: dict[str, tuple[float, TeacherNotice]] = field(default_factory=dict)  # by id
    notice_at: dict[str, float] = field(default_factory=dict)  # utterance -> its first notice
    understood_at: dict[str, float] = field(default_factory=dict)  # utterance -> understood
    feedback: dict[str, tuple[float, CreditedFeedback]] = field(default_factory=dict)  # by id


@dataclass
class Window:
    """What a fleet point's figures take: the window's observations (arrival, step, the
    simulator's wall time) and observation -> action lags (ms), and all the probe saw of the
    actions, the words, the notices and the feedback (by utterance: its first)."""

    obs: dict[str, list[tuple[float, int, float]]]
    lags: list[float]
    actions: dict[str, list[float]]
    said: dict[str, tuple[float, str, str]]
    understood_at: dict[str, float]
    feedback_at: dict[str, float]
    notices: list[tuple[float, TeacherNotice]]


class Probe:
    """A bus node of the harness, in a thread: what it saw and when (wall clock)."""

    def __init__(self, config: BusConfig, keep_obs: int = KEEP_OBS) -> None:
        self.config, self.keep_obs = config, keep_obs
        self.seen = Seen()
        self.present: set[str] = set()
        self.ready = threading.Event()
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(15)

    def nodes(self) -> set[str]:
        """The nodes present in the session now."""
        with self.lock:
            return set(self.present)

    def robots_seen(self) -> set[str]:
        with self.lock:
            return set(self.seen.obs)

    def _run(self) -> None:
        with Node("bench", self.config, quiet=True) as node:
            node.watch_presence()
            for topic in ("obs", "action", "feedback"):
                node.subscribe(topic)
            for topic in ("said", "utterance", "notice"):
                node.subscribe(topic)
            self.ready.set()
            while not self._stop.is_set():
                event = node.poll(0.2)
                if isinstance(event, Presence):
                    with self.lock:
                        (self.present.add if event.alive else self.present.discard)(event.node)
                elif isinstance(event, Input):
                    with self.lock:
                        self._on(event.message, time.time())

    def _on(self, m: object, now: float) -> None:
        seen = self.seen
        match m:
            case Observation():
                seen.obs[m.robot].append((now, m.step, m.wall_time))
                seen.obs_at[(m.robot, m.step)] = now
                if len(seen.obs_at) > self.keep_obs:  # oldest first: dicts keep order
                    del seen.obs_at[next(iter(seen.obs_at))]
            case Action():
                seen.actions[m.robot].append(now)
                at = seen.obs_at.get((m.robot, m.step))
                if at is not None:
                    seen.action_lag.append((now, now - at))
            case Said():
                seen.said.setdefault(m.id, (m.sent_at or now, m.teacher, m.robot))
            case Utterance():
                seen.utterances.setdefault(m.id, (now, m))
            case TeacherNotice():
                seen.notices.setdefault(m.id, (now, m))
                seen.notice_at.setdefault(m.utterance, now)
                if m.kind == "understood":
                    seen.understood_at.setdefault(m.utterance, now)
            case CreditedFeedback():
                seen.feedback.setdefault(m.id, (now, m))

    # -- what the benchmarks take of it ------------------------------------------------------
    def window(self, robots: tuple[str, ...], t0: float, t1: float) -> Window:
        """A copy of what it saw, the observations and lags within [t0, t1) (wall clock)."""
        seen = self.seen
        with self.lock:
            feedback_at: dict[str, float] = {}
            for at, fb in seen.feedback.values():  # in order of arrival
                for u in fb.sources:
                    feedback_at.setdefault(u, at)
            return Window(
                obs={r: [o for o in seen.obs.get(r, []) if t0 <= o[0] < t1] for r in robots},
                lags=[lag * 1000 for at, lag in seen.action_lag if t0 <= at < t1],
                actions={r: list(seen.actions.get(r, [])) for r in robots},
                said=dict(seen.said),
                understood_at=dict(seen.understood_at),
                feedback_at=feedback_at,
                notices=list(seen.notices.values()),
            )

    def latencies(self, since: float, until: float) -> dict[str, float | None]:
        """Medians and 95th percentiles (ms) within [since, until) (wall clock), with their
        sample counts: utterance -> its notice, utterance -> its feedback, obs -> action."""
        with self.lock:
            utterances = dict(self.seen.utterances)
            notice_at = dict(self.seen.notice_at)
            feedback = list(self.seen.feedback.values())
            lags = [lag for t, lag in self.seen.action_lag if since <= t < until]
        to_notice, to_feedback = [], []
        for uid, (t, _) in utterances.items():
            if since <= t < until and uid in notice_at:
                to_notice.append(notice_at[uid] - t)
        for at, fb in feedback:
            times = [utterances[u][0] for u in fb.sources if u in utterances]
            if times and since <= max(times) < until:
                to_feedback.append(at - max(times))
        return {
            **_percentiles("utterance_to_notice_ms", to_notice),
            **_percentiles("utterance_to_feedback_ms", to_feedback),
            **_percentiles("obs_to_action_ms", lags),
        }


def _percentiles(name: str, seconds: list[float]) -> dict[str, float | None]:
    ms = [s * 1000 for s in seconds]
    p50, p95 = percentile(ms, 50), percentile(ms, 95)
    return {
        f"{name}.p50": None if p50 is None else round(p50, 1),
        f"{name}.p95": None if p95 is None else round(p95, 1),
        f"{name}.n": len(ms),
    }

"""benchmarks/fleet.py's bus node: what the session's robots, teachers and services did and when.

A `Probe` runs a bus node of the harness in a thread: it follows which nodes are present and
notes, on the wall clock, every observation and action, every word said, utterance, notice
and credited feedback of the session; `window()` copies what a point's figures need.
"""

from __future__ import annotations

import threading
import time
from collections import defaultdict
from dataclasses import dataclass, field, replace

from protocol import (
    Action,
    CreditedFeedback,
    Observation,
    Said,
    TeacherNotice,
    Utterance,
    robot_key,
    teacher_key,
)
from services.runtime import Input, Node, Presence, bus_config

OBS_KEPT = 20_000  # (robot, step) arrivals kept to match actions to their observations


@dataclass
class Seen:
    obs: dict[str, list[tuple[float, int, float]]] = field(
        default_factory=lambda: defaultdict(list)
    )
    obs_at: dict[tuple[str, int], float] = field(default_factory=dict)  # (robot, step) -> at
    action_lag: list[tuple[float, float]] = field(default_factory=list)  # (at, obs -> action)
    actions: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))  # at
    said: dict[str, tuple[float, str, str]] = field(default_factory=dict)  # id: sent, who, robot
    utterances: dict[str, tuple[float, Utterance]] = field(default_factory=dict)
    notices: list[tuple[float, TeacherNotice]] = field(default_factory=list)
    understood_at: dict[str, float] = field(default_factory=dict)  # utterance id -> at
    feedback_at: dict[str, float] = field(default_factory=dict)  # utterance id -> at


@dataclass
class Window:
    """What a point's figures take from the probe: the window's observations (arrival, step,
    the simulator's wall time) and observation -> action lags (ms), and all it saw of the
    actions, the words, the notices and the feedback."""

    obs: dict[str, list[tuple[float, int, float]]]
    lags: list[float]
    actions: dict[str, list[float]]
    said: dict[str, tuple[float, str, str]]
    understood_at: dict[str, float]
    feedback_at: dict[str, float]
    notices: list[tuple[float, TeacherNotice]]


class Probe:
    """A bus node of the harness, in a thread: what it saw and when (wall clock)."""

    def __init__(self, session_id: str, router: str) -> None:
        self.session_id, self.router = session_id, router
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

    def robots_seen(self) -> set[str]:
        with self.lock:
            return set(self.seen.obs)

    def nodes(self) -> set[str]:
        """The nodes present in the session now."""
        with self.lock:
            return set(self.present)

    def web_teachers(self) -> int:
        return sum(1 for node in self.nodes() if node.startswith("web-"))

    def window(self, robots: tuple[str, ...], t0: float, t1: float) -> Window:
        """A copy of what it saw, the observations and lags within [t0, t1) (wall clock)."""
        seen = self.seen
        with self.lock:
            return Window(
                obs={r: [o for o in seen.obs.get(r, []) if t0 <= o[0] < t1] for r in robots},
                lags=[lag * 1000 for at, lag in seen.action_lag if t0 <= at < t1],
                actions={r: list(seen.actions.get(r, [])) for r in robots},
                said=dict(seen.said),
                understood_at=dict(seen.understood_at),
                feedback_at=dict(seen.feedback_at),
                notices=list(seen.notices),
            )

    def _run(self) -> None:
        config = replace(
            bus_config("bench", env={}),
            session=self.session_id,
            node="fleet-probe",
            mode="client",
            connect=(self.router,),
            connect_timeout=20.0,
        )
        s = self.session_id
        with Node("bench", config, quiet=True) as node:
            node.watch_presence()
            for topic in ("obs", "action", "feedback"):
                node.input(topic, robot_key(s, "*", topic))
            for topic in ("said", "utterance", "notice"):
                node.input(topic, teacher_key(s, "*", topic))
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
                if len(seen.obs_at) > OBS_KEPT:  # oldest first: dicts keep order
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
                seen.notices.append((now, m))
                if m.kind == "understood":
                    seen.understood_at.setdefault(m.utterance, now)
            case CreditedFeedback():
                for u in m.sources:
                    seen.feedback_at.setdefault(u, now)

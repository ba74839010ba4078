"""Who publishes and subscribes to what: the session's dataflow, declared once.

Each node role (the role a service gives its `Node`) runs under an access role, the router's
unit of permission (`voxshape/deploy/access.py` builds the access control from this table),
and publishes and subscribes to topics (voxshape/protocol/keys.py) of robots or of teachers: its own
(a simulator's robots, a teacher's own id) or any of the session's ("*"). A node announces
its presence as its node role, so an access role may announce as each of its node roles.
Nodes check what they declare against their row (`check`), `voxshape status` uses the table
to name inputs nobody publishes, and `voxshape dataflow --markdown` prints the table
docs/architecture.md shows.

How each topic reaches a subscriber that is slow, stopped or restarting is said once, per
topic (DELIVERY): a slow subscriber never makes a publisher wait (what its queue cannot take is
dropped for it alone, zenoh's DROP), so no observer can stall the control loop; each publisher
keeps its last `kept` messages of a key, and a subscriber that missed some gets them back
from there. A subscription says how far back a (re)joining subscriber asks (`recover_s`).
Nodes take all of it from here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from voxshape.protocol.keys import ROOT, SCOPES

ANY = "*"
Direction = Literal["publishes", "subscribes"]
DIRECTIONS: tuple[Direction, Direction] = ("publishes", "subscribes")
FlowScope = Literal["robot", "teacher"]
Owner = Literal["own", "*"]


class DataflowError(ValueError):
    """A node declared a key its role's row of the dataflow does not list."""


@dataclass(frozen=True)
class Delivery:
    """How one topic reaches a subscriber that is slow, stopped or restarting.

    `waits`: whether a slow subscriber may make the publisher wait (zenoh's BLOCK). Never for
    a topic an observer subscribes to (the logger records every topic), or an observer that
    stops stalls the robots. False: what a slow subscriber's queue cannot take is dropped for
    it alone (DROP); the others get everything at once.
    `kept`: how many messages of a key each publisher keeps; a subscriber that missed some
    (dropped while it was slow or stopped, published while it restarted) fetches them back.
    `after_stop`: what an observer stopped for a while (a logger, tens of seconds) has when
    it runs again: "all" (the publishers keep minutes of the topic at its fastest) or
    "recent" (a per-step stream: the last `kept` come back, the logger marks a gap for the
    rest)."""

    kept: int
    after_stop: Literal["all", "recent"]
    waits: bool = False

    def __str__(self) -> str:
        waits = "waits for a slow subscriber" if self.waits else "drops for a slow subscriber"
        back = "all come back" if self.after_stop == "all" else "the rest a marked gap"
        return f"keeps {self.kept}; {waits}; after a stop: {back}"


# What survives a restart or a stop (the constants the nodes take from here):
OBS_KEPT = 600  # a minute of steps at 10 Hz (the simulator keeps a minute at any --rtf)
STEPS_KEPT = 600  # other per-step topics (actions, learning summaries), as observations
FEEDBACK_KEPT = 1024  # per robot: minutes of feedback at the teachers' rate limits
UTTERANCES_KEPT = 256  # per teacher: as many as speech and the arbiter recover in 30 s
AUDIO_KEPT = 800  # per teacher: 40 s of 50 ms chunks
EVENTS_KEPT = 256  # episodes, interventions, notices: minutes of them at their fastest
RARE_KEPT = 64  # questions, answers, a robot placed, clock probes
RECOVER_S = 30.0  # what the arbiter and speech ask for on joining
FEEDBACK_RECOVER_S = 60.0  # what a learner asks for; older is about steps out of its window
ALL_KEPT = math.inf  # a subscription that asks for whatever is kept, however old (limits)

DELIVERY: dict[tuple[FlowScope, str], Delivery] = {
    ("robot", "obs"): Delivery(OBS_KEPT, "recent"),
    ("robot", "action"): Delivery(STEPS_KEPT, "recent"),
    ("robot", "learning"): Delivery(STEPS_KEPT, "recent"),
    ("robot", "episode"): Delivery(EVENTS_KEPT, "all"),
    ("robot", "feedback"): Delivery(FEEDBACK_KEPT, "all"),
    ("robot", "teaching"): Delivery(EVENTS_KEPT, "all"),
    ("robot", "help"): Delivery(RARE_KEPT, "all"),
    ("robot", "answer"): Delivery(RARE_KEPT, "all"),
    ("robot", "limits"): Delivery(1, "all"),
    ("robot", "learnt"): Delivery(RARE_KEPT, "all"),
    ("teacher", "audio"): Delivery(AUDIO_KEPT, "recent"),
    ("teacher", "utterance"): Delivery(UTTERANCES_KEPT, "all"),
    ("teacher", "said"): Delivery(UTTERANCES_KEPT, "all"),
    ("teacher", "clock"): Delivery(RARE_KEPT, "recent"),
    ("teacher", "clock-reply"): Delivery(RARE_KEPT, "recent"),
    ("teacher", "notice"): Delivery(EVENTS_KEPT, "all"),
    ("teacher", "placed"): Delivery(RARE_KEPT, "all"),
}
UNLISTED = Delivery(0, "recent")  # a key outside the protocol (tests, tools): not kept


def delivery_of(key: str) -> Delivery:
    """How the topic of `key` is delivered (UNLISTED for a key that is not one of a topic)."""
    scope, _, topic = topic_of(key).partition("/")
    return DELIVERY.get((scope, topic), UNLISTED)  # type: ignore[call-overload]


@dataclass(frozen=True)
class Flow:
    """A topic of robots or teachers: its own ("own") or any of the session's ("*"); a
    subscription may recover what was published in the last `recover_s` seconds."""

    scope: FlowScope
    owner: Owner
    topic: str
    recover_s: float = 0.0

    def __str__(self) -> str:
        return f"{self.scope}/{'<own>' if self.owner == 'own' else ANY}/{self.topic}"

    @property
    def delivery(self) -> Delivery:
        return DELIVERY[(self.scope, self.topic)]

    def described(self, direction: Direction, quote: str = "") -> str:
        return f"{quote}{self}{quote}{_survives(self, direction)}"


def _survives(flow: Flow, direction: Direction) -> str:
    """What survives a restart, as the tables say it: a publisher keeps N, a subscriber
    recovers S seconds."""
    if direction == "publishes":
        return f" (keeps {flow.delivery.kept})" if flow.delivery.kept else ""
    if flow.recover_s == ALL_KEPT:
        return " (recovers what is kept)"
    return f" (recovers {flow.recover_s:g} s)" if flow.recover_s else ""


@dataclass(frozen=True)
class NodeRole:
    access: str  # the access role it runs under (deploy/access.toml); "*": under any
    summary: str
    publishes: tuple[Flow, ...] = ()
    subscribes: tuple[Flow, ...] = ()
    everything: bool = False  # every key of the session, unchecked (logger, launcher, tools)

    def flows(self, direction: Direction) -> tuple[Flow, ...]:
        return self.publishes if direction == "publishes" else self.subscribes


def _flows(scope: FlowScope, owner: Owner, *topics: str) -> tuple[Flow, ...]:
    return tuple(Flow(scope, owner, topic) for topic in topics)


def _recovered(scope: FlowScope, owner: Owner, topic: str, seconds: float) -> Flow:
    return Flow(scope, owner, topic, recover_s=seconds)


DATAFLOW: dict[str, NodeRole] = {
    "sim": NodeRole(
        "simulator",
        "steps its robots: observations and episode events out, actions in",
        publishes=_flows("robot", "own", "obs", "episode", "limits"),
        subscribes=_flows("robot", "own", "action"),
    ),
    "ros2": NodeRole(
        "simulator",
        "a real ROS 2 robot (voxshape ros2), to the session as the simulator's: observations "
        "and episode events out, actions in; a teacher's word that it is back at its start",
        publishes=_flows("robot", "own", "obs", "episode", "limits"),
        subscribes=(*_flows("robot", "own", "action"), *_flows("teacher", ANY, "placed")),
    ),
    "learner": NodeRole(
        "learner",
        "learns from its robot's observations and credited feedback; decides its actions",
        publishes=_flows("robot", "own", "action", "learning", "help"),
        subscribes=(
            *_flows("robot", "own", "obs"),
            _recovered("robot", "own", "feedback", FEEDBACK_RECOVER_S),
            _recovered("robot", "own", "limits", ALL_KEPT),
        ),
    ),
    "arbiter": NodeRole(
        "arbiter",
        "turns every teacher's utterances into credited feedback on the robots' step clocks",
        publishes=(
            *_flows("robot", ANY, "feedback", "teaching", "answer"),
            *_flows("teacher", ANY, "notice", "clock-reply"),
        ),
        subscribes=(
            _recovered("robot", ANY, "obs", RECOVER_S),
            *_flows("robot", ANY, "help"),
            _recovered("teacher", ANY, "utterance", RECOVER_S),
            *_flows("teacher", ANY, "clock"),
        ),
    ),
    "speech": NodeRole(
        "speech",
        "recognizes every teacher's audio (or a mock's said text) as utterances",
        publishes=_flows("teacher", ANY, "utterance", "notice"),
        subscribes=(
            _recovered("teacher", ANY, "audio", RECOVER_S),
            _recovered("teacher", ANY, "said", RECOVER_S),
        ),
    ),
    "teacher": NodeRole(
        "teacher",
        "a person's client (voxshape teach): speaks or types as itself, watches a robot",
        publishes=_flows("teacher", "own", "audio", "utterance", "said", "clock", "placed"),
        subscribes=(
            *_flows("teacher", "own", "utterance", "notice", "clock-reply"),
            *_flows("robot", ANY, "obs", "episode", "feedback", "help", "answer"),
        ),
    ),
    "simteacher": NodeRole(
        "teacher",
        "the simulated teacher: watches a robot and speaks as itself",
        publishes=_flows("teacher", "own", "audio", "said", "clock"),
        subscribes=(
            *_flows("teacher", "own", "notice", "clock-reply"),
            *_flows("robot", ANY, "obs", "help"),
        ),
    ),
    "web": NodeRole(
        "observer",
        "the teachers' web page (voxshape web): shows every robot to the browsers; each "
        "browser's teacher is a teacher node of its own",
        subscribes=_flows(
            "robot", ANY, "obs", "episode", "feedback", "teaching", "help", "answer", "learnt"
        ),
    ),
    "logger": NodeRole("admin", "records every message of the session", everything=True),
    "launcher": NodeRole(
        "admin",
        "voxshape up and the demo: watch the session; the demo says when a robot has learnt",
        publishes=_flows("robot", ANY, "learnt"),
        everything=True,
    ),
    "listen": NodeRole("admin", "voxshape listen: prints every message", everything=True),
    "bench": NodeRole(
        "admin", "benchmarks: play the other roles on a session of their own", everything=True
    ),
    "equivalence": NodeRole(
        "admin", "the distributed experiment: watches a session of its own", everything=True
    ),
    "router": NodeRole("admin", "the router's own node: logs who joins and leaves"),
    "status": NodeRole(ANY, "voxshape status: who is present (every user may look)"),
}


def topic_of(key: str) -> str:
    """`scope/topic` of a key of the bus (the key itself if it is not one)."""
    parts = key.split("/")
    return f"{parts[2]}/{parts[4]}" if len(parts) == 5 and parts[0] == ROOT else key


def _covers(flow: Flow, key: str) -> bool:
    # An own flow is of a concrete robot or teacher: a wildcard there would reach others'.
    if topic_of(key) != f"{flow.scope}/{flow.topic}":
        return False
    return flow.owner == ANY or "*" not in key.split("/")[3]


def flow_of(role: str, direction: Direction, key: str) -> Flow | None:
    """The flow of `role`'s row that covers `key` (None: a role outside the table, or with
    everything, or a key its row does not list)."""
    row = DATAFLOW.get(role)
    if row is None or row.everything:
        return None
    return next((flow for flow in row.flows(direction) if _covers(flow, key)), None)


def check(role: str, direction: Direction, key: str) -> None:
    """Raises DataflowError if a node of `role` may not publish (subscribe to) `key`; roles
    outside the table (tests) and those with everything are not checked."""
    row = DATAFLOW.get(role)
    if row is None or row.everything:
        return
    if not any(_covers(flow, key) for flow in row.flows(direction)):
        verb = "publishes" if direction == "publishes" else "subscribes to"
        listed = ", ".join(map(str, row.flows(direction))) or "nothing"
        raise DataflowError(
            f"the {role} node {verb} {key!r}, which is not declared in "
            f"voxshape/protocol/dataflow.py (its {role} row {direction}: {listed}; <own> is one "
            "robot or teacher id, not a wildcard); declare it there (the router's access control "
            "follows) or drop it"
        )


def publishers_of(scope: str, topic: str) -> list[str]:
    """The node roles that publish `scope`/`topic` (those with everything aside)."""
    return [
        role
        for role, row in DATAFLOW.items()
        if any(f.scope == scope and f.topic == topic for f in row.publishes)
    ]


def _cells(row: NodeRole, quote: str = "") -> list[str]:
    if row.everything:
        return ["everything in the session"] * 2
    return [", ".join(f.described(d, quote) for f in row.flows(d)) or "nothing" for d in DIRECTIONS]


def markdown() -> str:
    """The table as markdown (docs/architecture.md shows it)."""
    lines = ["| node role | access role | publishes | subscribes to |", "|---|---|---|---|"]
    for role, row in DATAFLOW.items():
        access = "any" if row.access == ANY else row.access
        lines.append(f"| {role} | {access} | {' | '.join(_cells(row, '`'))} |")
    return "\n".join(lines)


def text() -> str:
    """The table as plain text, a paragraph a node role."""
    out = []
    for role, row in DATAFLOW.items():
        access = "any" if row.access == ANY else row.access
        out.append(f"{role} (access role {access}): {row.summary}")
        for direction, cell in zip(DIRECTIONS, _cells(row), strict=True):
            out.append(f"  {direction:<10} {cell}")
    return "\n".join(out)


def docstring(role: str) -> str:
    """A role's row as its node's module docstring shows it: `Inputs:` and `Outputs:`, a key a
    line (`<robot>`, `<teacher>`: its own; `*`: any of the session's), with the type it carries
    and what survives a restart (`voxshape dataflow --docstring ROLE` prints it)."""
    row = DATAFLOW[role]
    if row.everything:
        return f"Inputs:  {ROOT}/<session>/**  everything in the session\nOutputs: nothing"
    sides = {"Inputs: ": row.subscribes, "Outputs:": row.publishes}
    keys = {f: f"{ROOT}/<session>/{f.scope}/{_owner(f)}/{f.topic}" for f in _flows_of(row)}
    width = max((len(k) for k in keys.values()), default=0) + 2
    lines = []
    for (label, flows), direction in zip(sides.items(), ("subscribes", "publishes"), strict=True):
        for i, f in enumerate(flows):
            extra = _survives(f, direction)  # type: ignore[arg-type]
            kind = SCOPES[f.scope][f.topic].__name__
            lines.append(f"{label if i == 0 else '':<9}{keys[f]:<{width}}{kind}{extra}")
        if not flows:
            lines.append(f"{label} nothing")
    return "\n".join(lines)


def _owner(flow: Flow) -> str:
    return f"<{flow.scope}>" if flow.owner == "own" else ANY


def _flows_of(row: NodeRole) -> tuple[Flow, ...]:
    return (*row.subscribes, *row.publishes)


def delivery_markdown() -> str:
    """The delivery table as markdown (docs/reliability.md shows it)."""
    lines = [
        "| topic | a slow subscriber | kept per key | an observer after a stop |",
        "|---|---|---|---|",
    ]
    for (scope, topic), d in DELIVERY.items():
        slow = "makes the publisher wait" if d.waits else "dropped for it alone"
        back = "gets all back" if d.after_stop == "all" else "gets the last kept, a gap marked"
        lines.append(f"| `{scope}/{topic}` | {slow} | {d.kept} | {back} |")
    return "\n".join(lines)


def _check_table() -> None:
    for role, row in DATAFLOW.items():
        for flow in (*row.publishes, *row.subscribes):
            assert flow.topic in SCOPES[flow.scope], f"{role}: unknown topic {flow}"
    topics = {(scope, topic) for scope, topics in SCOPES.items() for topic in topics}
    assert set(DELIVERY) == topics, f"DELIVERY must list every topic: {topics ^ set(DELIVERY)}"
    # An observer (the logger records everything) that stops would stall a waiting publisher.
    assert not any(d.waits for d in DELIVERY.values()), "no topic may wait: the logger observes all"


_check_table()

"""Who publishes and subscribes to what: the session's dataflow, declared once.

Each node role (the role a service gives its `Node`) runs under an access role, the router's
unit of permission (`services/deploy/access.py` builds the access control from this table),
and publishes and subscribes to topics (protocol/keys.py) of robots or of teachers: its own
(a simulator's robots, a teacher's own id) or any of the session's ("*"). A node announces
its presence as its node role, so an access role may announce as each of its node roles.
Nodes check what they declare against their row (`check`), `voxshape status` uses the table
to name inputs nobody publishes, and `voxshape dataflow --markdown` prints the table
docs/architecture.md shows.

What must survive a restart is said on its flow: a publisher keeps its last `kept` messages
of a key, and a subscriber that (re)joins asks for what was published in the last
`recover_s` seconds (and for what it missed meanwhile). Nodes take both from here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from protocol.keys import ROOT, SCOPES

ANY = "*"
Direction = Literal["publishes", "subscribes"]
DIRECTIONS: tuple[Direction, Direction] = ("publishes", "subscribes")
FlowScope = Literal["robot", "teacher"]
Owner = Literal["own", "*"]


class DataflowError(ValueError):
    """A node declared a key its role's row of the dataflow does not list."""


@dataclass(frozen=True)
class Flow:
    """A topic of robots or teachers: its own ("own") or any of the session's ("*"); kept by
    its publisher (messages), recovered by its subscriber (seconds)."""

    scope: FlowScope
    owner: Owner
    topic: str
    kept: int = 0
    recover_s: float = 0.0

    def __str__(self) -> str:
        return f"{self.scope}/{'<own>' if self.owner == 'own' else ANY}/{self.topic}"

    def described(self, quote: str = "") -> str:
        extra = f" (keeps {self.kept})" if self.kept else ""
        extra += f" (recovers {self.recover_s:g} s)" if self.recover_s else ""
        return f"{quote}{self}{quote}{extra}"


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


# What survives a restart (the constants the nodes take from here):
OBS_KEPT = 600  # a minute of steps at 10 Hz (the simulator keeps a minute at any --rtf)
FEEDBACK_KEPT = 1024  # per robot: minutes of feedback at the teachers' rate limits
UTTERANCES_KEPT = 256  # per teacher: as many as speech and the arbiter recover in 30 s
AUDIO_KEPT = 800  # per teacher: 40 s of 50 ms chunks
RECOVER_S = 30.0  # what the arbiter and speech ask for on joining
FEEDBACK_RECOVER_S = 60.0  # what a learner asks for; older is about steps out of its window


def _kept(scope: FlowScope, owner: Owner, topic: str, kept: int) -> Flow:
    return Flow(scope, owner, topic, kept=kept)


def _recovered(scope: FlowScope, owner: Owner, topic: str, seconds: float) -> Flow:
    return Flow(scope, owner, topic, recover_s=seconds)


DATAFLOW: dict[str, NodeRole] = {
    "sim": NodeRole(
        "simulator",
        "steps its robots: observations and episode events out, actions in",
        publishes=(_kept("robot", "own", "obs", OBS_KEPT), *_flows("robot", "own", "episode")),
        subscribes=_flows("robot", "own", "action"),
    ),
    "ros2": NodeRole(
        "simulator",
        "a real ROS 2 robot (voxshape ros2), to the session as the simulator's: observations "
        "and episode events out, actions in; a teacher's word that it is back at its start",
        publishes=(_kept("robot", "own", "obs", OBS_KEPT), *_flows("robot", "own", "episode")),
        subscribes=(*_flows("robot", "own", "action"), *_flows("teacher", ANY, "placed")),
    ),
    "learner": NodeRole(
        "learner",
        "learns from its robot's observations and credited feedback; decides its actions",
        publishes=_flows("robot", "own", "action", "learning", "help"),
        subscribes=(
            *_flows("robot", "own", "obs"),
            _recovered("robot", "own", "feedback", FEEDBACK_RECOVER_S),
        ),
    ),
    "arbiter": NodeRole(
        "arbiter",
        "turns every teacher's utterances into credited feedback on the robots' step clocks",
        publishes=(
            _kept("robot", ANY, "feedback", FEEDBACK_KEPT),
            *_flows("robot", ANY, "teaching", "answer"),
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
        publishes=(
            _kept("teacher", ANY, "utterance", UTTERANCES_KEPT),
            *_flows("teacher", ANY, "notice"),
        ),
        subscribes=(
            _recovered("teacher", ANY, "audio", RECOVER_S),
            _recovered("teacher", ANY, "said", RECOVER_S),
        ),
    ),
    "teacher": NodeRole(
        "teacher",
        "a person's client (voxshape teach): speaks or types as itself, watches a robot",
        publishes=(
            _kept("teacher", "own", "audio", AUDIO_KEPT),
            _kept("teacher", "own", "utterance", UTTERANCES_KEPT),
            _kept("teacher", "own", "said", UTTERANCES_KEPT),
            *_flows("teacher", "own", "clock", "placed"),
        ),
        subscribes=(
            *_flows("teacher", "own", "utterance", "notice", "clock-reply"),
            *_flows("robot", ANY, "obs", "episode", "feedback", "help", "answer"),
        ),
    ),
    "simteacher": NodeRole(
        "teacher",
        "the simulated teacher: watches a robot and speaks as itself",
        publishes=(
            _kept("teacher", "own", "audio", AUDIO_KEPT),
            _kept("teacher", "own", "said", UTTERANCES_KEPT),
            *_flows("teacher", "own", "clock"),
        ),
        subscribes=(
            *_flows("teacher", "own", "notice", "clock-reply"),
            *_flows("robot", ANY, "obs", "help"),
        ),
    ),
    "web": NodeRole(
        "observer",
        "the teachers' web page (voxshape web): shows every robot to the browsers; each "
        "browser's teacher is a teacher node of its own",
        subscribes=_flows("robot", ANY, "obs", "episode", "feedback", "teaching", "help", "answer"),
    ),
    "logger": NodeRole("admin", "records every message of the session", everything=True),
    "launcher": NodeRole("admin", "voxshape up and the demo: watch the session", everything=True),
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
            f"the {role} node {verb} {key!r}, which is not declared in protocol/dataflow.py "
            f"(its {role} row {direction}: {listed}; <own> is one robot or teacher id, not "
            "a wildcard); declare it there (the router's access control follows) or drop it"
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
    return [", ".join(f.described(quote) for f in row.flows(d)) or "nothing" for d in DIRECTIONS]


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
    for label, flows in sides.items():
        for i, f in enumerate(flows):
            extra = f" (keeps {f.kept})" if f.kept else ""
            extra += f" (recovers {f.recover_s:g} s)" if f.recover_s else ""
            kind = SCOPES[f.scope][f.topic].__name__
            lines.append(f"{label if i == 0 else '':<9}{keys[f]:<{width}}{kind}{extra}")
        if not flows:
            lines.append(f"{label} nothing")
    return "\n".join(lines)


def _owner(flow: Flow) -> str:
    return f"<{flow.scope}>" if flow.owner == "own" else ANY


def _flows_of(row: NodeRole) -> tuple[Flow, ...]:
    return (*row.subscribes, *row.publishes)


def _check_table() -> None:
    for role, row in DATAFLOW.items():
        for flow in (*row.publishes, *row.subscribes):
            assert flow.topic in SCOPES[flow.scope], f"{role}: unknown topic {flow}"


_check_table()

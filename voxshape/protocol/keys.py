"""Key expressions of the bus, and which message type travels on each.

voxshape/<session>/robot/<robot>/obs              Observation
voxshape/<session>/robot/<robot>/action           Action
voxshape/<session>/robot/<robot>/episode          EpisodeEvent
voxshape/<session>/robot/<robot>/feedback         CreditedFeedback
voxshape/<session>/robot/<robot>/learning         LearningSummary
voxshape/<session>/robot/<robot>/teaching         TeachingStats (interventions, teacher stats)
voxshape/<session>/robot/<robot>/help             HelpRequest (the robot asks which way)
voxshape/<session>/robot/<robot>/answer           HelpAnswer (who answered, with what)
voxshape/<session>/robot/<robot>/limits           RobotLimits (how fast it may be driven)
voxshape/<session>/robot/<robot>/learnt           Learnt (it has learnt its task: the demo says)
voxshape/<session>/teacher/<teacher>/audio        AudioChunk
voxshape/<session>/teacher/<teacher>/utterance    Utterance
voxshape/<session>/teacher/<teacher>/said         Said (a teacher's text, for the mock engine)
voxshape/<session>/teacher/<teacher>/clock        ClockProbe (NTP style)
voxshape/<session>/teacher/<teacher>/clock-reply  ClockReply
voxshape/<session>/teacher/<teacher>/notice       TeacherNotice (understood, or why not)
voxshape/<session>/teacher/<teacher>/placed       Placed (a real robot is back at its start)
voxshape/<session>/presence/<role>/<node>         liveliness token of every running node
voxshape/<session>/router/access                  a query: the access file the router enforces
                                                  (AccessAnswer, voxshape/protocol/queries.py)

Who publishes and who subscribes to each: voxshape/protocol/dataflow.py (`voxshape dataflow`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal

from voxshape.protocol.messages import (
    ID_HINT,
    ID_PATTERN,
    Action,
    AudioChunk,
    ClockProbe,
    ClockReply,
    CreditedFeedback,
    EpisodeEvent,
    HelpAnswer,
    HelpRequest,
    LearningSummary,
    Learnt,
    Message,
    Observation,
    Placed,
    RobotLimits,
    Said,
    TeacherNotice,
    TeachingStats,
    Utterance,
)
from voxshape.protocol.schema import ProtocolError

ROOT = "voxshape"

ROBOT_TOPICS: dict[str, type[Message]] = {
    "obs": Observation,
    "action": Action,
    "episode": EpisodeEvent,
    "feedback": CreditedFeedback,
    "learning": LearningSummary,
    "teaching": TeachingStats,
    "help": HelpRequest,
    "answer": HelpAnswer,
    "limits": RobotLimits,
    "learnt": Learnt,
}
TEACHER_TOPICS: dict[str, type[Message]] = {
    "audio": AudioChunk,
    "utterance": Utterance,
    "said": Said,
    "clock": ClockProbe,
    "clock-reply": ClockReply,
    "notice": TeacherNotice,
    "placed": Placed,
}
SCOPES: dict[str, dict[str, type[Message]]] = {"robot": ROBOT_TOPICS, "teacher": TEACHER_TOPICS}
# Each type travels on one topic, so a message's key follows from it (`message_key`).
TOPIC_OF: dict[type[Message], tuple[str, str]] = {
    kind: (scope, topic) for scope, topics in SCOPES.items() for topic, kind in topics.items()
}

Scope = Literal["robot", "teacher", "presence"]
_ID = re.compile(ID_PATTERN)


def check_id(value: object, what: str) -> str:
    """Returns `value` if it is safe as one key-expression chunk, else raises ProtocolError."""
    if not isinstance(value, str):
        raise ProtocolError(what, f"expected a str id, got {type(value).__name__}")
    if not _ID.fullmatch(value):
        bad = sorted({c for c in value if c in "/*$?#@ "})
        why = f"contains {' '.join(repr(c) for c in bad)}" if bad else "is not a valid id"
        raise ProtocolError(what, f"{value!r} {why}: {ID_HINT}")
    return value


def _topic(scope: str, topic: str) -> str:
    if topic not in SCOPES[scope]:
        known = ", ".join(SCOPES[scope])
        raise ProtocolError("topic", f"unknown {scope} topic {topic!r}; known: {known}")
    return topic


def robot_key(session: str, robot: str, topic: str) -> str:
    """`voxshape/<session>/robot/<robot>/<topic>`; `robot="*"` subscribes to every robot."""
    robot = robot if robot == "*" else check_id(robot, "robot")
    return f"{ROOT}/{check_id(session, 'session')}/robot/{robot}/{_topic('robot', topic)}"


def teacher_key(session: str, teacher: str, topic: str) -> str:
    """`voxshape/<session>/teacher/<teacher>/<topic>`; `teacher="*"` for every teacher."""
    teacher = teacher if teacher == "*" else check_id(teacher, "teacher")
    return f"{ROOT}/{check_id(session, 'session')}/teacher/{teacher}/{_topic('teacher', topic)}"


def message_key(session: str, message: Message) -> str:
    """The key `message` travels on: its type's topic, of its robot (a robot topic) or its
    teacher (a teacher topic)."""
    if type(message) not in TOPIC_OF:
        raise ProtocolError("message", f"{type(message).__name__} travels on no topic")
    scope, topic = TOPIC_OF[type(message)]
    if scope == "robot":
        return robot_key(session, message.robot, topic)  # type: ignore[attr-defined]
    return teacher_key(session, message.teacher, topic)  # type: ignore[attr-defined]


def presence_key(session: str, role: str = "*", node: str = "*") -> str:
    """Liveliness token key of a node; wildcards (the defaults) for watching."""
    role = role if role == "*" else check_id(role, "role")
    node = node if node == "*" else check_id(node, "node")
    return f"{ROOT}/{check_id(session, 'session')}/presence/{role}/{node}"


def presence_in_every_session() -> str:
    """Every node's presence token in every session (of a router several sessions share)."""
    return f"{ROOT}/*/presence/*/*"


def router_access_key(session: str) -> str:
    """The query any user may ask the session's router: which access file it enforces."""
    return f"{ROOT}/{check_id(session, 'session')}/router/access"


def session_keys(session: str) -> str:
    """Everything published in a session."""
    return f"{ROOT}/{check_id(session, 'session')}/**"


@dataclass(frozen=True)
class Key:
    """A parsed key: `owner` is the robot, teacher or (for presence) role; `name` the topic
    or (for presence) node id."""

    session: str
    scope: Scope
    owner: str
    name: str

    @property
    def message_type(self) -> type[Message] | None:
        """The type carried on this key (None for presence tokens, which carry nothing)."""
        return SCOPES[self.scope][self.name] if self.scope in SCOPES else None


def parse_key(key: str) -> Key:
    """Parses a concrete key of the bus; raises ProtocolError saying what does not fit."""
    parts = str(key).split("/")
    if len(parts) != 5 or parts[0] != ROOT:
        raise ProtocolError("key", f"{key!r} is not {ROOT}/<session>/<scope>/<id>/<name>")
    _, session, scope, owner, name = parts
    check_id(session, "session")
    check_id(owner, "role" if scope == "presence" else scope)
    if scope == "presence":
        check_id(name, "node")
    elif scope in SCOPES:
        _topic(scope, name)
    else:
        raise ProtocolError(
            "key", f"unknown scope {scope!r} in {key!r}; known: robot, teacher, presence"
        )
    return Key(session, scope, owner, name)  # type: ignore[arg-type]

"""Who may do what on a secured session's bus: users, their roles, and zenoh's access control.

Pure: no zenoh import. `voxshape router` turns an access file (deploy/access.toml) and a
credentials file (`user:password` lines, zenoh's own dictionary format) into the router's
`transport.auth.usrpwd` and `access_control` settings. Deny by default: a user may do only
what its role grants, in the router's session only. A role's rights come from the dataflow
table (voxshape/protocol/dataflow.py), every key expression from voxshape/protocol/keys.py.

An access file:

    [users]
    logger = { role = "admin" }
    sim = { role = "simulator", robots = ["r1"] }   # "*" for every robot
    ana = { role = "teacher" }                      # a teacher's user name is its teacher id
"""

from __future__ import annotations

import hashlib
import tomllib
from dataclasses import dataclass
from pathlib import Path

from voxshape.protocol import (
    ProtocolError,
    check_id,
    presence_key,
    robot_key,
    session_keys,
    teacher_key,
)
from voxshape.protocol.dataflow import DATAFLOW, Direction
from voxshape.protocol.queries import AccessAnswer, router_access_key

ANY = "*"
ACCESS_FILE = Path("deploy") / "access.toml"


class AccessError(ValueError):
    """An access or credentials file that cannot work; the message names the file, the entry
    and the fix."""


@dataclass(frozen=True)
class Role:
    """What a role may do. Topics are (scope, owner, topic); an owner of "self" is the user's own
    teacher id, "robots" the user's robots, "*" any robot or teacher of the session."""

    summary: str
    publish: tuple[tuple[str, str, str], ...] = ()
    subscribe: tuple[tuple[str, str, str], ...] = ()
    announce: tuple[str, ...] = ()  # presence roles it may hold a token as
    everything: bool = False  # every message on every key of the session
    takes_robots: bool = False


# What a flow's "own" owner is, for a user: its teacher id, or the robots it is given.
_OWN = {"teacher": "self", "robot": "robots"}
_SUMMARIES = {
    "simulator": "its robots' observations and episodes; their actions (and, for a real "
    "robot, teachers' word that it is placed)",
    "learner": "its robots' actions and learning summaries; their observations and feedback",
    "arbiter": "credited feedback, teaching stats, notices, clock replies; observations, "
    "utterances, clock probes",
    "speech": "utterances of every teacher; their audio and said text",
    "teacher": "speak or type as itself, say a real robot is placed; see the robots "
    "(observations, episodes, feedback) and its notices",
    "observer": "see the robots (observations, episodes, feedback, teaching stats); publish "
    "nothing (the web page's gateway)",
    "admin": "everything in the session (logger, launcher, tools)",
}


def _role(access: str) -> Role:
    """An access role's rights: the union of its node roles' rows in voxshape/protocol/dataflow.py
    (and of those any user may run, such as `voxshape status`)."""
    rows = [(name, row) for name, row in DATAFLOW.items() if row.access in (access, ANY)]

    def union(direction: Direction) -> tuple[tuple[str, str, str], ...]:
        flows = [f for _, row in rows for f in row.flows(direction)]
        triples = ((f.scope, _OWN[f.scope] if f.owner == "own" else ANY, f.topic) for f in flows)
        return tuple(dict.fromkeys(triples))

    publish, subscribe = union("publishes"), union("subscribes")
    return Role(
        _SUMMARIES[access],
        publish=publish,
        subscribe=subscribe,
        announce=tuple(name for name, _ in rows),
        everything=any(row.everything for _, row in rows),
        takes_robots=any(owner == "robots" for _, owner, _ in (*publish, *subscribe)),
    )


# The access roles, in the table's order; a summary missing here fails at import.
ROLES: dict[str, Role] = {
    access: _role(access)
    for access in dict.fromkeys(row.access for row in DATAFLOW.values() if row.access != ANY)
}
# The presence role of `voxshape status`, which every user may run (compose healthchecks do).
STATUS_ROLE = "status"


@dataclass(frozen=True)
class User:
    name: str
    role: str
    robots: tuple[str, ...] = ()


def find_access_file(start: Path | None = None) -> Path:
    """deploy/access.toml in the current directory or the checkout this package runs from."""
    for folder in (start or Path.cwd(), Path(__file__).resolve().parents[2]):
        if (folder / ACCESS_FILE).is_file():
            return folder / ACCESS_FILE
    raise AccessError(f"no {ACCESS_FILE} here or in the voxshape checkout: pass --access FILE")


def load_access(path: Path) -> dict[str, User]:
    """The users of an access file, checked: known roles, valid ids, robots where needed."""
    try:
        document = tomllib.loads(Path(path).read_text())
    except OSError as e:
        raise AccessError(f"access file {str(path)!r}: {e.strerror}") from None
    except tomllib.TOMLDecodeError as e:
        raise AccessError(f"access file {path}: not valid TOML: {e}") from None
    unknown = set(document) - {"users"}
    if unknown:
        raise AccessError(f"access file {path}: unknown section(s) {sorted(unknown)}; only [users]")
    entries = document.get("users")
    if not isinstance(entries, dict) or not entries:
        raise AccessError(f'access file {path}: no [users]; e.g. ana = {{ role = "teacher" }}')
    return {name: _user(path, name, entry) for name, entry in entries.items()}


def _user(path: Path, name: str, entry: object) -> User:
    where = f"access file {path}: user {name!r}"
    try:
        check_id(name, "user")
    except ProtocolError as e:
        raise AccessError(f"{where}: {e}") from None
    if not isinstance(entry, dict):
        raise AccessError(f'{where}: expected a table like {{ role = "teacher" }}')
    unknown = set(entry) - {"role", "robots"}
    if unknown:
        raise AccessError(f"{where}: unknown key(s) {sorted(unknown)}; known: role, robots")
    role = entry.get("role")
    if role not in ROLES:
        raise AccessError(f"{where}: role {role!r} is not one of {', '.join(ROLES)}")
    robots = entry.get("robots", [])
    if not ROLES[role].takes_robots:
        if robots:
            raise AccessError(f"{where}: a {role} has no robots of its own; remove `robots`")
    elif not (isinstance(robots, list) and robots):
        raise AccessError(f'{where}: a {role} needs its robots, e.g. robots = ["r1"] or ["*"]')
    for robot in robots:
        try:
            robot == ANY or check_id(robot, "robot")
        except ProtocolError as e:
            raise AccessError(f"{where}: {e}") from None
    return User(name, role, tuple(robots))


def load_credentials(path: Path) -> dict[str, str]:
    """`user:password` lines (zenoh's dictionary format); blank lines and # comments skipped."""
    try:
        text = Path(path).read_text()
    except OSError as e:
        raise AccessError(
            f"credentials file {str(path)!r}: {e.strerror}; `voxshape certs DIR` makes one"
        ) from None
    credentials: dict[str, str] = {}
    for number, line in enumerate(text.splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        user, colon, password = line.partition(":")
        where = f"credentials file {path} line {number}"
        if not colon or not password:
            raise AccessError(f"{where}: expected user:password")
        try:
            check_id(user, "user")
        except ProtocolError as e:
            raise AccessError(f"{where}: {e}") from None
        if user in credentials:
            raise AccessError(f"{where}: user {user!r} appears twice")
        credentials[user] = password
    if not credentials:
        raise AccessError(f"credentials file {path}: no user:password line")
    return credentials


def _key(session: str, user: User, scope: str, owner: str, topic: str) -> list[str]:
    owners = {"self": [user.name], "robots": list(user.robots)}.get(owner, [owner])
    make = robot_key if scope == "robot" else teacher_key
    return [make(session, o, topic) for o in owners]


def _rule(rule_id: str, messages: list[str], keys: list[str], flow: str) -> dict:
    assert keys, f"rule {rule_id} has no key expression"
    return {
        "id": rule_id,
        "permission": "allow",
        "messages": messages,
        "key_exprs": sorted(set(keys)),
        "flows": [flow],
    }


def access_control(session: str, users: dict[str, User]) -> dict:
    """zenoh's `access_control` settings for a router of `session`: deny by default, each user
    (matched by the name it authenticated with) allowed what its role grants."""
    everything = session_keys(session)
    presence = presence_key(session)
    shared = [
        # Who is present: look (tokens of others come as egress tokens), and be told of
        # subscribers so that publishers know someone listens (matching status).
        _rule(
            "look-at-presence",
            ["liveliness_query", "declare_liveliness_subscriber"],
            [presence],
            "ingress",
        ),
        _rule("see-presence", ["liveliness_token"], [presence], "egress"),
        _rule(
            "learn-of-subscribers",
            ["declare_subscriber", "declare_liveliness_subscriber"],
            [everything],
            "egress",
        ),
        # Which access file the router enforces (voxshape/protocol/queries.py): `voxshape web` asks.
        _rule("ask-router-access", ["query"], [router_access_key(session)], "ingress"),
        _rule("hear-router-access", ["reply"], [router_access_key(session)], "egress"),
    ]
    rules, subjects, policies = list(shared), [], []
    for name, user in users.items():
        role = ROLES[user.role]
        own = []
        if role.everything:  # and what kept outputs say under @adv (the logger recovers)
            every = [everything, *_adv([everything])]
            own.append(_rule(f"{name}:all-in", ALL_MESSAGES, every, "ingress"))
            own.append(_rule(f"{name}:all-out", ALL_MESSAGES, every, "egress"))
        else:
            published = [k for t in role.publish for k in _key(session, user, *t)]
            subscribed = [k for t in role.subscribe for k in _key(session, user, *t)]
            tokens = [presence_key(session, r, "*") for r in role.announce]
            if published:  # a role may publish nothing (an observer)
                own.append(_rule(f"{name}:publish", ["put"], published, "ingress"))
            own.append(_rule(f"{name}:subscribe", ["declare_subscriber"], subscribed, "ingress"))
            own.append(_rule(f"{name}:receive", ["put"], subscribed, "egress"))
            own.append(_rule(f"{name}:announce", ["liveliness_token"], tokens, "ingress"))
            own += _kept_and_recovering(name, published, subscribed)
        rules += own
        subjects.append({"id": f"user:{name}", "usernames": [name]})
        policies.append(
            {
                "id": name,
                "rules": [r["id"] for r in own] + [r["id"] for r in shared],
                "subjects": [f"user:{name}"],
            }
        )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def _adv(keys: list[str]) -> list[str]:
    # "@adv" is a verbatim chunk: `**` never matches it, so it is spelt out.
    return [f"{k}/@adv/**" for k in keys]


def _kept_and_recovering(name: str, published: list[str], subscribed: list[str]) -> list[dict]:
    """zenoh's advanced publishers and subscribers (voxshape/runtime/flows.py: kept outputs,
    recovering inputs) talk under `<key>/@adv/...`: the publisher announces itself, sends
    heartbeats and answers the subscribers' queries for what they missed with the messages
    themselves (replies on `<key>`). Only a user who may publish `<key>` may answer for it."""
    token = ["liveliness_token", "declare_liveliness_subscriber", "liveliness_query"]
    recovering = [
        _rule(
            f"{name}:recover",
            ["query", "declare_subscriber", *token],
            _adv(subscribed),
            "ingress",
        ),
        _rule(
            f"{name}:recovered",
            ["reply", "put", "liveliness_token"],
            subscribed + _adv(subscribed),
            "egress",
        ),
    ]
    if not published:  # an observer: nothing to keep or answer for
        return recovering
    return [
        _rule(f"{name}:keep", ["put", "declare_queryable", *token], _adv(published), "ingress"),
        _rule(f"{name}:answer", ["reply"], published + _adv(published), "ingress"),
        _rule(f"{name}:asked", ["query", "liveliness_token"], _adv(published), "egress"),
        *recovering,
    ]


ALL_MESSAGES = [
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "declare_queryable",
    "reply",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
]


def check_consistent(users: dict[str, User], credentials: dict[str, str]) -> list[str]:
    """Warnings: users who cannot log in (no password) or may do nothing (no role)."""
    warnings = []
    for name in sorted(set(users) - set(credentials)):
        warnings.append(f"user {name!r} has a role but no password: it cannot log in")
    for name in sorted(set(credentials) - set(users)):
        warnings.append(f"user {name!r} has a password but no role: it may do nothing")
    return warnings


def access_digest(path: Path) -> str:
    """SHA-256 of an access file's contents (what a router says it enforces)."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError as e:
        raise AccessError(f"access file {str(path)!r}: {e.strerror}") from None


def compare_with_router(
    path: Path, digest: str, answers: list[AccessAnswer], routers: set[str]
) -> tuple[str | None, str | None]:
    """(error, warning) of a node that takes users from `path` (SHA-256 `digest`) on a
    secured session, given the answers to router_access_key and the zenoh ids of the routers
    it is connected to: its router must enforce the very same file."""
    fix = "pass the same --access (VOXSHAPE_ACCESS) to the router and to this service"
    mine = [a for a in answers if a.zid in routers]
    if not mine:
        others = f" (only {', '.join(a.router for a in answers)} of another site did)"
        return None, (
            f"the router did not say which access file it enforces{others if answers else ''}:"
            f" not a voxshape router, or an older one. Teachers are taken from {path}; if the "
            f"router enforces another file, its teachers are refused here: {fix}"
        )
    for answer in mine:
        if answer.open:
            return (
                f"the router (node {answer.router}) is open (no passwords, no access control): a "
                "secured page would let anyone in as any teacher. Secure the router "
                "(--secrets DIR) or serve the page without a user (no VOXSHAPE_SECRETS)"
            ), None
        if answer.sha256 != digest:
            return (
                f"the router (node {answer.router}) enforces the access file {answer.path} (sha256 "
                f"{answer.sha256[:12]}...), but this service takes its teachers from {path} "
                f"(sha256 {digest[:12]}...): {fix}"
            ), None
    return None, None

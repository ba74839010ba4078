"""The access file a router enforces, on the bus: the router answers router_access_key
(voxshape/protocol/queries.py) and a service that takes users from an access file of its own
(`voxshape web`: who is a teacher) asks at start, to compare (access.compare_with_router)."""

from __future__ import annotations

import contextlib
import time
from pathlib import Path

import zenoh

from voxshape.deploy.access import access_digest
from voxshape.protocol import ProtocolError
from voxshape.protocol.queries import AccessAnswer, router_access_key

ASK_TIMEOUT_S = 3.0  # a router answers within milliseconds; this long only when none does


def serve_access(
    session: zenoh.Session, session_id: str, router: str, path: Path | None
) -> zenoh.Queryable:
    """The router's answer, to any user who asks (None: an open router). Keep the returned
    queryable for as long as the router runs."""
    answer = AccessAnswer(
        router,
        str(session.zid()),
        str(Path(path).resolve()) if path is not None else None,
        access_digest(path) if path is not None else None,
    ).to_bytes()
    key = router_access_key(session_id)

    def on_query(query: zenoh.Query) -> None:
        with contextlib.suppress(zenoh.ZError):  # the querier left
            query.reply(key, answer)

    return session.declare_queryable(key, on_query)


def ask_access(
    session: zenoh.Session, session_id: str, patience: float = ASK_TIMEOUT_S
) -> tuple[list[AccessAnswer], set[str]]:
    """Every router's answer (two sites' routers mesh: both answer), and the zenoh ids of the
    routers this session is connected to (to tell its own router's answer). Asked again for
    `patience` seconds while its own router has not answered (a router just started)."""
    deadline = time.monotonic() + patience
    while True:
        answers = _ask(session, session_id)
        routers = {str(zid) for zid in session.info.routers_zid()}
        if any(a.zid in routers for a in answers) or time.monotonic() >= deadline:
            return answers, routers
        time.sleep(0.25)


def _ask(session: zenoh.Session, session_id: str) -> list[AccessAnswer]:
    replies = session.get(
        router_access_key(session_id),
        target=zenoh.QueryTarget.ALL,
        consolidation=zenoh.ConsolidationMode.NONE,
        timeout=ASK_TIMEOUT_S,
    )
    answers = []
    for reply in replies:  # until every queryable answered, or the timeout
        if reply.ok is None:
            continue
        try:
            answers.append(AccessAnswer.from_bytes(reply.ok.payload.to_bytes()))
        except ProtocolError:
            continue
    return answers

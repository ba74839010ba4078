"""What a node may ask the session's router (zenoh queries), and the answers, as JSON.

voxshape/<session>/router/access    AccessAnswer: the access file the router enforces

Any user of a secured router may ask (voxshape/deploy/access.py allows it), so `voxshape web`
can check at start that it lets in the teachers its router lets in (docs/web.md#security).
An answer names the file as the router's own file system sees it and a SHA-256 of its
contents; an open router (no passwords) answers with neither.
"""

from __future__ import annotations

import json
import re
from dataclasses import asdict, dataclass

from voxshape.protocol.keys import router_access_key
from voxshape.protocol.schema import ProtocolError

__all__ = ["AccessAnswer", "router_access_key"]

MAX_ANSWER_BYTES = 4096
_SHA256 = re.compile(r"[0-9a-f]{64}")
_ZID = re.compile(r"[0-9a-f]{1,32}")


@dataclass(frozen=True)
class AccessAnswer:
    """A router's answer: its node id, its zenoh id (a client tells its own router's answer
    by it, when two sites' routers mesh), and its access file's path and SHA-256 (None: an
    open router, no access control)."""

    router: str
    zid: str
    path: str | None
    sha256: str | None

    @property
    def open(self) -> bool:
        return self.sha256 is None

    def to_bytes(self) -> bytes:
        return json.dumps(asdict(self)).encode()

    @classmethod
    def from_bytes(cls, data: bytes) -> AccessAnswer:
        """Raises ProtocolError naming what does not fit."""
        if len(data) > MAX_ANSWER_BYTES:
            raise ProtocolError("access answer", f"over {MAX_ANSWER_BYTES} bytes")
        try:
            fields = json.loads(data)
        except (ValueError, UnicodeDecodeError):
            raise ProtocolError("access answer", "not JSON") from None
        if not isinstance(fields, dict) or set(fields) != {"router", "zid", "path", "sha256"}:
            raise ProtocolError("access answer", "expected router, zid, path and sha256")
        router, zid, path, sha256 = (fields[k] for k in ("router", "zid", "path", "sha256"))
        if not isinstance(router, str) or not isinstance(zid, str) or not _ZID.fullmatch(zid):
            raise ProtocolError("access answer", "router and zid must be a name and a zenoh id")
        if (path is None) != (sha256 is None):
            raise ProtocolError("access answer", "path and sha256 go together")
        if sha256 is not None and not (isinstance(path, str) and _SHA256.fullmatch(sha256)):
            raise ProtocolError("access answer", "sha256 must be 64 lowercase hex digits")
        return cls(router, zid, path, sha256)

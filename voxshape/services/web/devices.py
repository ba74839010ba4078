"""Device cookies (OWASP's "device cookies" against lockout), pure: a browser that has logged in
as a teacher is given a token signed by the gateway, which the page keeps as an HttpOnly
cookie; its next logins as that teacher count under the throttle's key of that browser only,
so strangers failing as the teacher, from anywhere, never hold her up (docs/web.md#security).

A token is `<user>:<nonce>:<issued>:<mac>`: the user id, 128 random bits, the Unix second it
was issued and an HMAC-SHA256 of the rest (base64url), under a key derived from the gateway's
own secret (its bus password: tokens outlive a restart) or random per process.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import re
import secrets
from dataclasses import dataclass

from voxshape.protocol.messages import ID_PATTERN

DEVICE_TTL_S = 90 * 24 * 3600  # a token (and its cookie) is good for 90 days after its login
COOKIE_PREFIX = "voxshape-device-"  # one cookie per teacher: voxshape-device-<user>
COOKIE_PATH = "/ws"  # sent with the socket's handshake (and to /ws/device), nowhere else
MAX_TOKEN_CHARS = 200
_TOKEN = re.compile(rf"({ID_PATTERN}):([0-9a-f]{{32}}):([0-9]{{1,12}}):([A-Za-z0-9_-]{{43}})")
_CONTEXT = b"voxshape web device cookies v1"


def device_secret(password: str | None) -> bytes:
    """The signing key: derived from the gateway's bus password, else random (tokens then
    last as long as the process)."""
    if password:
        return hmac.new(password.encode(), _CONTEXT, hashlib.sha256).digest()
    return secrets.token_bytes(32)


def cookie_name(user: str) -> str:
    return COOKIE_PREFIX + user


@dataclass(frozen=True)
class Device:
    user: str
    nonce: str
    issued: int


class DeviceTokens:
    """Issues and checks tokens under one key."""

    def __init__(self, secret: bytes, ttl_s: int = DEVICE_TTL_S) -> None:
        self._secret, self.ttl_s = secret, ttl_s

    def _mac(self, body: str) -> str:
        digest = hmac.new(self._secret, body.encode(), hashlib.sha256).digest()
        return base64.urlsafe_b64encode(digest).decode().rstrip("=")

    def issue(self, user: str, now: float) -> str:
        body = f"{user}:{secrets.token_hex(16)}:{int(now)}"
        return f"{body}:{self._mac(body)}"

    def verify(self, token: object, now: float) -> Device | None:
        """The device of a token this gateway signed, not expired; None for anything else."""
        if not isinstance(token, str) or len(token) > MAX_TOKEN_CHARS:
            return None
        match = _TOKEN.fullmatch(token)
        if match is None:
            return None
        user, nonce, issued, mac = match.groups()
        if not hmac.compare_digest(mac, self._mac(token.rsplit(":", 1)[0])):
            return None
        if not -60 <= now - int(issued) <= self.ttl_s:  # a minute of clock steps allowed
            return None
        return Device(user, nonce, int(issued))

    def age_left(self, device: Device, now: float) -> int:
        """Seconds its cookie may still live."""
        return max(0, int(device.issued + self.ttl_s - now))

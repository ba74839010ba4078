"""What a browser sends, read strictly: a frame's size and JSON, a finite number in it, and
the login that must come first; BrowserError says what cannot be used, and is sent back."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

from voxshape.protocol import ProtocolError, check_id

MAX_TEXT_BYTES = 4 * 1024  # a JSON frame from a browser
MAX_BINARY_BYTES = 64 * 1024  # an audio frame from a browser (2 s of audio)
MAX_MESSAGES_PER_S = 50  # frames of one socket, text and binary together


class BrowserError(ValueError):
    """Something a browser sent that cannot be used; the text is sent back as an "error"."""


@dataclass(frozen=True)
class Login:
    teacher: str
    user: str | None
    password: str | None


def parse_login(data: dict[str, Any], secured: bool) -> Login:
    """The first message of a socket; BrowserError says why it cannot log in. On a secured
    session the teacher id is the user name (the only one its router lets it speak as)."""
    if data.get("type") != "login":
        raise BrowserError('log in first: the first message must be {"type": "login", ...}')
    user, password = data.get("user") or None, data.get("password") or None
    if secured:
        if not (isinstance(user, str) and isinstance(password, str)):
            raise BrowserError("this session is secured: log in with your user name and password")
        teacher = user
    else:
        teacher = data.get("teacher") or user
        user = password = None
    try:
        return Login(check_id(teacher, "teacher"), user, password)
    except ProtocolError as e:
        raise BrowserError(f"not a usable teacher id: {e.problem}") from None


def finite_number(data: dict[str, Any], name: str) -> float:
    """Field `name` of a frame as a finite float; BrowserError naming it if it is not one (a
    bool, a string, NaN or infinity, an integer of hundreds of digits)."""
    value = data.get(name)
    try:
        number = float(value) if isinstance(value, int | float) else math.nan
    except OverflowError:  # an integer of hundreds of digits
        number = math.nan
    if isinstance(value, bool) or not math.isfinite(number):
        raise BrowserError(f"{data.get('type')!s:.20}: {name} must be a finite number")
    return number


def parse_frame(text: str) -> dict[str, Any]:
    """A browser's JSON frame, at most MAX_TEXT_BYTES; BrowserError if it is not usable."""
    if len(text) > MAX_TEXT_BYTES or len(text.encode()) > MAX_TEXT_BYTES:
        raise BrowserError(f"a text message is over {MAX_TEXT_BYTES} bytes")
    try:
        data = json.loads(text)
    except (ValueError, RecursionError):
        raise BrowserError("not JSON (or nested too deep)") from None
    if not isinstance(data, dict):
        raise BrowserError('a message is a JSON object with a "type"')
    return data

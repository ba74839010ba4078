"""What an event-log record is: a known message, a valid message of a type this build does not
know, a node joining or leaving, a gap (messages the logger missed for good), or something
rejected (and why). Pure, no bus."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import msgpack

from voxshape.protocol import (
    MESSAGE_TYPES,
    SCHEMA_VERSION,
    Key,
    Message,
    ProtocolError,
    decode,
    parse_key,
)
from voxshape.protocol.keys import ROOT
from voxshape.services.logger.eventlog import EventRecord


@dataclass(frozen=True)
class Known:
    record: EventRecord
    key: Key | None  # None on a key this build's protocol does not list
    message: Message


@dataclass(frozen=True)
class Unknown:
    """A well-formed message (schema version, `type`) of a type this build does not know."""

    record: EventRecord
    type_name: str
    fields: dict[str, Any]


@dataclass(frozen=True)
class PresenceChange:
    record: EventRecord
    role: str
    node: str
    alive: bool


@dataclass(frozen=True)
class Rejected:
    record: EventRecord
    problem: str


@dataclass(frozen=True)
class Gap:
    """Messages on `record.key` that the logger missed and could not get back: it was stopped
    for longer than their publisher keeps them."""

    record: EventRecord
    missed: int


Decoded = Known | Unknown | PresenceChange | Gap | Rejected


def decode_record(record: EventRecord) -> Decoded:
    """Decodes one record as strictly as a service would, but never raises."""
    parts = record.key.split("/")
    if len(parts) == 5 and parts[0] == ROOT and parts[2] == "presence":
        return PresenceChange(record, parts[3], parts[4], record.kind == "put")
    if record.kind == "gap":
        return _gap(record)
    if record.kind != "put":
        return Rejected(record, f"a {record.kind} on a message key")
    try:
        key: Key | None = parse_key(record.key)
    except ProtocolError:
        key = None  # a topic added after this build: decode by the message's own type
    try:
        expected = key.message_type if key is not None else None
        return Known(record, key, decode(record.payload, expected))
    except ProtocolError as e:
        unknown = _unknown_type(record)
        return unknown if unknown is not None else Rejected(record, str(e))


def _unknown_type(record: EventRecord) -> Unknown | None:
    """A msgpack map in this schema version whose type this build does not know."""
    try:
        wire = msgpack.unpackb(record.payload, raw=False, strict_map_key=False)
    except Exception:  # any unpacking failure means: not a message at all
        return None
    if not isinstance(wire, dict) or wire.get("schema") != SCHEMA_VERSION:
        return None
    type_name = wire.get("type")
    if not isinstance(type_name, str) or not type_name:
        return None
    if type_name in MESSAGE_TYPES:
        return None  # a known type that failed validation: rejected, not unknown
    fields = {str(k): v for k, v in wire.items() if k not in ("schema", "type")}
    return Unknown(record, type_name[:64], fields)


def _gap(record: EventRecord) -> Gap | Rejected:
    try:
        missed = msgpack.unpackb(record.payload, raw=False)["missed"]
    except Exception:  # any unpacking failure means: not a gap the logger wrote
        return Rejected(record, "a gap record without a count of missed messages")
    if not isinstance(missed, int) or missed < 0:
        return Rejected(record, f"a gap record missing {missed!r} messages")
    return Gap(record, missed)

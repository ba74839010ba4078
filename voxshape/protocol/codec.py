"""msgpack codec: a message is one map with `schema` (version) and `type`, then its fields."""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

import msgpack

from voxshape.protocol.messages import MESSAGE_TYPES, Message
from voxshape.protocol.schema import ProtocolError, checker_for

SCHEMA_VERSION = 1
MAX_PAYLOAD_BYTES = 64 * 1024

M = TypeVar("M", bound=Message)


def _no_extensions(code: int, data: bytes) -> None:
    raise ProtocolError("payload", f"msgpack extension type {code} is not part of the protocol")


def to_wire(msg: Message) -> dict[str, Any]:
    """The map that goes on the wire (also handy for printing as JSON)."""
    fields = {f.name: getattr(msg, f.name) for f in dataclasses.fields(msg)}
    return {"schema": SCHEMA_VERSION, "type": msg.TYPE, **_plain(fields)}


def _plain(value: Any) -> Any:
    if dataclasses.is_dataclass(value):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, tuple) and value and dataclasses.is_dataclass(value[0]):
        return [_plain(v) for v in value]
    return value


def encode(msg: Message) -> bytes:
    """Validates `msg` as strictly as `decode` would, then packs it."""
    wire = to_wire(msg)
    fields = {k: v for k, v in wire.items() if k not in ("schema", "type")}
    checker_for(type(msg))(fields, type(msg).__name__)
    data = msgpack.packb(wire, use_bin_type=True)
    if len(data) > MAX_PAYLOAD_BYTES:
        raise ProtocolError("payload", f"{len(data)} bytes exceeds {MAX_PAYLOAD_BYTES}")
    return data


def decode(data: bytes, expect: type[M] | None = None) -> M:
    """Unpacks and validates one message; raises ProtocolError naming the field and problem.

    `expect` is the type the topic carries: anything else is rejected.
    """
    if len(data) > MAX_PAYLOAD_BYTES:
        raise ProtocolError("payload", f"{len(data)} bytes exceeds {MAX_PAYLOAD_BYTES}")
    try:
        wire = msgpack.unpackb(data, raw=False, strict_map_key=True, ext_hook=_no_extensions)
    except ProtocolError:
        raise
    except (ValueError, TypeError, msgpack.UnpackException) as e:  # ExtraData, bad UTF-8...
        raise ProtocolError("payload", f"not a msgpack message ({type(e).__name__}: {e})") from e
    if not isinstance(wire, dict):
        raise ProtocolError("payload", f"expected a map, got {type(wire).__name__}")
    version = wire.pop("schema", None)
    if version != SCHEMA_VERSION or type(version) is not int:
        raise ProtocolError(
            "schema", f"unknown schema version {version!r}; this build speaks {SCHEMA_VERSION}"
        )
    type_name = wire.pop("type", None)
    cls = MESSAGE_TYPES.get(type_name) if isinstance(type_name, str) else None
    if cls is None:
        raise ProtocolError("type", f"unknown message type {type_name!r}")
    if expect is not None and cls is not expect:
        raise ProtocolError("type", f"{type_name!r} where {expect.TYPE!r} was expected")
    return checker_for(cls)(wire, cls.__name__)

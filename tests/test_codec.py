"""The msgpack codec: round trips of every type, and every kind of malformed input rejected
with an error naming the field and the problem."""

from __future__ import annotations

import ast
import contextlib
import dataclasses
import inspect
import math

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import voxshape.protocol.messages
from tests.strategies import any_message, messages
from voxshape.protocol import (
    MAX_PAYLOAD_BYTES,
    MESSAGE_TYPES,
    SCHEMA_VERSION,
    Action,
    AudioChunk,
    CreditedFeedback,
    Observation,
    ProtocolError,
    decode,
    encode,
    to_wire,
)
from voxshape.protocol.examples import example_messages

EXAMPLES = {m.TYPE: m for _, m in example_messages("s1")}
ALL_TYPES = sorted(MESSAGE_TYPES)


def pack(wire: dict) -> bytes:
    return msgpack.packb(wire, use_bin_type=True)


def wire_of(type_name: str) -> dict:
    return to_wire(EXAMPLES[type_name])


def rejected(data: bytes, expect: type | None = None) -> ProtocolError:
    with pytest.raises(ProtocolError) as info:
        decode(data, expect)
    return info.value


def test_every_message_type_has_an_example():
    assert set(EXAMPLES) == set(MESSAGE_TYPES)


@pytest.mark.parametrize("type_name", ALL_TYPES)
@settings(max_examples=60, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_round_trip_of_every_type(type_name, data):
    message = data.draw(messages(MESSAGE_TYPES[type_name]))
    assert decode(encode(message), MESSAGE_TYPES[type_name]) == message


@settings(max_examples=200)
@given(any_message)
def test_encoding_carries_version_type_id_and_sender_clock(message):
    wire = msgpack.unpackb(encode(message))
    assert wire["schema"] == SCHEMA_VERSION
    assert wire["type"] == message.TYPE
    assert wire["id"] == message.id and wire["sender"] == message.sender
    assert wire["sent_at"] == message.sent_at


# -- malformed input: each kind rejected, naming the field -----------------------------------


@pytest.mark.parametrize("type_name", ALL_TYPES)
def test_missing_field_is_named(type_name):
    for field in [f for f in wire_of(type_name) if f not in ("schema", "type")]:
        wire = wire_of(type_name)
        del wire[field]
        error = rejected(pack(wire))
        assert error.field.endswith(field) and "missing" in error.problem


@pytest.mark.parametrize("type_name", ALL_TYPES)
def test_wrong_type_of_every_field_is_named(type_name):
    for field, value in wire_of(type_name).items():
        if field in ("schema", "type"):
            continue
        wrong = {"x": 1} if not isinstance(value, dict) else "not a map"
        wire = {**wire_of(type_name), field: wrong}
        error = rejected(pack(wire))
        assert error.field.startswith(f"{MESSAGE_TYPES[type_name].__name__}.{field}"), error


def test_unknown_field_is_rejected_not_ignored():
    wire = {**wire_of("observation"), "colour": "red"}
    error = rejected(pack(wire))
    assert error.field == "Observation.colour" and "unknown field" in error.problem


@pytest.mark.parametrize(
    ("type_name", "field", "value", "problem"),
    [
        ("observation", "laser", [1.0, -0.5], "outside"),
        ("observation", "laser", [1.0, float("nan")], "not a finite number"),
        ("observation", "x", float("inf"), "not a finite number"),
        ("observation", "theta", 4.0, "outside"),
        ("observation", "step", -1, "outside"),
        ("observation", "step", 2**40, "outside"),
        ("observation", "episode", True, "expected an int"),
        ("observation", "x", "1.0", "expected a float"),
        ("observation", "laser", [1.0] * 1082, "at most 1081"),
        ("action", "discrete", 5, "outside"),
        ("action", "chooser", "robot", "not one of"),
        ("audio", "sample_rate", 44100, "not one of"),
        ("audio", "pcm", "text, not bytes", "expected bytes"),
        ("audio", "pcm", b"\x00" * 32002, "at most 32000"),
        ("utterance", "confidence", 1.5, "outside"),
        ("utterance", "teacher", "ana/bob", "not allowed"),
        ("utterance", "teacher", "", "not allowed"),
        ("utterance", "language", "French", "ISO 639 code"),
        ("said", "language", "e", "ISO 639 code"),
        ("utterance", "text", "x" * 501, "at most 500"),
        ("feedback", "command", "jump", "not one of"),
        ("feedback", "credits", [], "at least 1"),
        ("feedback", "sources", ["not-a-uuid"], "not allowed"),
        ("learning", "epsilon", -0.1, "outside"),
        ("episode", "kind", "crash", "not one of"),
    ],
)
def test_out_of_range_and_wrong_values(type_name, field, value, problem):
    wire = {**wire_of(type_name), field: value}
    error = rejected(pack(wire))
    assert field in error.field and problem in error.problem, error


def test_nested_field_errors_name_the_path():
    wire = wire_of("feedback")
    wire["credits"][1]["weight"] = 2.0
    error = rejected(pack(wire))
    assert error.field == "CreditedFeedback.credits[1].weight"


@pytest.mark.parametrize(
    ("type_name", "changes", "field"),
    [
        ("action", {"discrete": None, "v": None, "omega": None}, "Action.discrete"),
        ("action", {"v": 0.5, "omega": None}, "Action.v"),
        ("utterance", {"onset": 100.0, "end": 99.0}, "Utterance.end"),
        ("feedback", {"kind": "command"}, "CreditedFeedback.command"),
        ("feedback", {"reward": None}, "CreditedFeedback.reward"),
        ("audio", {"pcm": b"\x00\x01\x02"}, "AudioChunk.pcm"),
    ],
)
def test_cross_field_rules(type_name, changes, field):
    error = rejected(pack({**wire_of(type_name), **changes}))
    assert error.field == field


def test_credit_weights_may_not_sum_above_one():
    wire = wire_of("feedback")
    wire["credits"] = [{"step": 1, "weight": 0.7}, {"step": 2, "weight": 0.7}]
    assert "sum" in rejected(pack(wire)).problem


def test_unknown_or_missing_schema_version():
    for version in (2, 0, "1", None, True):
        error = rejected(pack({**wire_of("action"), "schema": version}))
        assert error.field == "schema" and "this build speaks 1" in error.problem
    wire = wire_of("action")
    del wire["schema"]
    assert rejected(pack(wire)).field == "schema"


def test_unknown_type_and_unexpected_type():
    assert rejected(pack({**wire_of("action"), "type": "teleport"})).field == "type"
    error = rejected(encode(EXAMPLES["action"]), Observation)
    assert error.field == "type" and "'observation' was expected" in error.problem


def test_oversized_payload_rejected_before_unpacking():
    error = rejected(b"\x00" * (MAX_PAYLOAD_BYTES + 1))
    assert error.field == "payload" and "exceeds" in error.problem


def test_encoding_refuses_what_decoding_would_reject():
    with pytest.raises(ProtocolError, match=r"Observation\.x"):
        encode(dataclasses.replace(EXAMPLES["observation"], x=math.nan))
    with pytest.raises(ProtocolError, match=r"Action\.discrete"):
        encode(dataclasses.replace(EXAMPLES["action"], discrete=None, v=None, omega=None))


@pytest.mark.parametrize(
    ("data", "problem"),
    [
        (b"", "not a msgpack message"),
        (b"\xc1", "not a msgpack message"),  # reserved byte
        (pack(wire_of("action"))[:-2], "not a msgpack message"),  # truncated
        (pack(wire_of("action")) + b"\x00", "not a msgpack message"),  # trailing bytes
        (pack([1, 2, 3]), "expected a map"),
        (msgpack.packb({1: 2}), "not a msgpack message"),  # non-string keys
        (msgpack.packb(msgpack.ExtType(5, b"x")), "extension type 5"),
        (b"\xa2\xff\xfe", "not a msgpack message"),  # invalid UTF-8 in a str
    ],
)
def test_garbage_is_rejected(data, problem):
    error = rejected(data)
    assert error.field == "payload" and problem in error.problem


@settings(max_examples=500)
@given(st.binary(max_size=300))
def test_random_bytes_never_crash(data):
    """Random bytes give a valid message or a ProtocolError, never another exception."""
    with contextlib.suppress(ProtocolError):
        assert encode(decode(data))


msgpack_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**63), 2**64 - 1)
    | st.floats()
    | st.text(max_size=8)
    | st.binary(max_size=8),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4)
    ),
    max_leaves=12,
)


@settings(max_examples=300)
@given(base=any_message, field=st.integers(0, 30), value=msgpack_values)
def test_any_value_in_any_field_is_either_valid_or_rejected(base, field, value):
    """Property-based fuzz: whatever a sender puts in a field, decode returns a valid message
    or a ProtocolError naming that field, never another exception."""
    wire = to_wire(base)
    names = [k for k in wire if k not in ("schema", "type")]
    name = names[field % len(names)]
    wire[name] = value
    try:
        message = decode(pack(wire))
    except ProtocolError as e:
        cls = type(base).__name__
        assert e.field.startswith(f"{cls}.{name}") or e.field in CROSS_FIELD_RULES, e
    else:
        assert encode(message)  # whatever was accepted is a valid message


def cross_field_rules() -> set[str]:
    """Fields named by the `check()` rules that relate several fields, read from
    voxshape/protocol/messages.py, so that a new rule cannot be missing from this list."""
    tree = ast.parse(inspect.getsource(voxshape.protocol.messages))
    checks = [f for f in ast.walk(tree) if isinstance(f, ast.FunctionDef) and f.name == "check"]
    return {
        call.args[0].value
        for check in checks
        for call in ast.walk(check)
        if isinstance(call, ast.Call) and getattr(call.func, "id", None) == "ProtocolError"
    }


CROSS_FIELD_RULES = cross_field_rules()


def test_the_cross_field_rules_are_read_from_the_messages():
    assert {"Action.v", "CreditedFeedback.credits", "ClockProbe.offset"} <= CROSS_FIELD_RULES


def test_decode_is_strict_about_bool_versus_number():
    wire = {**wire_of("audio"), "final": 1}
    assert "expected a bool" in rejected(pack(wire)).problem
    ok = decode(pack({**wire_of("observation"), "x": 2}))  # int where float: lossless
    assert ok.x == 2.0 and type(ok.x) is float


def test_example_messages_validate():
    for message in EXAMPLES.values():
        assert decode(encode(message)) == message
    assert isinstance(EXAMPLES["feedback"], CreditedFeedback)
    assert isinstance(EXAMPLES["audio"], AudioChunk) and isinstance(EXAMPLES["action"], Action)

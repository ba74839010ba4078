"""Key-expression builders and parsers, and ids that would break a key expression."""

from __future__ import annotations

import pytest
from hypothesis import given

from tests.strategies import ids
from voxshape.protocol import (
    ROBOT_TOPICS,
    TEACHER_TOPICS,
    Message,
    Observation,
    ProtocolError,
    Utterance,
    parse_key,
    presence_key,
    robot_key,
    session_keys,
    teacher_key,
)
from voxshape.protocol.examples import example_messages
from voxshape.protocol.keys import TOPIC_OF, message_key


def test_the_design_keys():
    assert robot_key("lab", "r1", "obs") == "voxshape/lab/robot/r1/obs"
    assert teacher_key("lab", "ana", "utterance") == "voxshape/lab/teacher/ana/utterance"
    assert presence_key("lab", "sim", "sim-1") == "voxshape/lab/presence/sim/sim-1"
    assert presence_key("lab") == "voxshape/lab/presence/*/*"
    assert robot_key("lab", "*", "action") == "voxshape/lab/robot/*/action"
    assert session_keys("lab") == "voxshape/lab/**"


def test_parse_gives_the_message_type_of_each_topic():
    assert parse_key("voxshape/lab/robot/r1/obs").message_type is Observation
    assert parse_key("voxshape/lab/teacher/ana/utterance").message_type is Utterance
    key = parse_key("voxshape/lab/presence/logger/logger-1")
    assert (key.scope, key.owner, key.name, key.message_type) == (
        "presence",
        "logger",
        "logger-1",
        None,
    )


@given(session=ids, owner=ids)
def test_build_then_parse_round_trips(session, owner):
    for topic, cls in ROBOT_TOPICS.items():
        key = parse_key(robot_key(session, owner, topic))
        assert (key.session, key.scope, key.owner, key.name) == (session, "robot", owner, topic)
        assert key.message_type is cls
    for topic in TEACHER_TOPICS:
        assert parse_key(teacher_key(session, owner, topic)).owner == owner


@pytest.mark.parametrize(
    "bad",
    ["", "a/b", "r*", "**", "$x", "a?b", "a#b", "two words", "@admin", "x" * 65, "-lead", "ñandú"],
)
def test_ids_that_would_break_a_key_are_rejected(bad):
    with pytest.raises(ProtocolError) as info:
        robot_key("lab", bad, "obs")
    assert info.value.field == "robot" and "use 1-64 of" in info.value.problem
    with pytest.raises(ProtocolError, match="session"):
        teacher_key(bad, "ana", "audio")


def test_error_names_the_offending_characters():
    with pytest.raises(ProtocolError, match=r"contains '/'"):
        teacher_key("lab", "ana/bob", "audio")


@pytest.mark.parametrize(
    "bad",
    [
        "voxshape/lab/robot/r1",  # too short
        "voxshape/lab/robot/r1/obs/extra",
        "other/lab/robot/r1/obs",
        "voxshape/lab/robot/r1/teleport",
        "voxshape/lab/teacher/ana/obs",  # robot topic under a teacher
        "voxshape/lab/planet/r1/obs",
        "voxshape/l*b/robot/r1/obs",
    ],
)
def test_parse_rejects_keys_outside_the_design(bad):
    with pytest.raises(ProtocolError):
        parse_key(bad)


def test_unknown_topic_lists_the_known_ones():
    with pytest.raises(ProtocolError, match="known: obs, action, episode, feedback, learning"):
        robot_key("lab", "r1", "odometry")


def test_a_message_travels_on_the_key_of_its_type():
    """message_key (Node.publish's): the type's one topic, of its robot or teacher; the key
    each example of voxshape/protocol/examples.py is published on, for every topic."""
    examples = example_messages("lab", robot="r1", teacher="ana")
    assert {type(m) for _, m in examples} == set(TOPIC_OF)  # every topic has an example
    for key, message in examples:
        assert message_key("lab", message) == key
    with pytest.raises(ProtocolError, match="Message travels on no topic"):
        message_key("lab", Message())  # the envelope alone

"""The voxshape wire protocol: message types, msgpack codec, key expressions, vocabulary.

The single source of truth for everything that crosses a process boundary.
"""

from protocol.codec import MAX_PAYLOAD_BYTES, SCHEMA_VERSION, decode, encode, to_wire
from protocol.keys import (
    ROBOT_TOPICS,
    TEACHER_TOPICS,
    Key,
    check_id,
    parse_key,
    presence_key,
    robot_key,
    session_keys,
    teacher_key,
)
from protocol.messages import (
    ACTION_NAMES,
    MESSAGE_TYPES,
    Action,
    Alternative,
    AudioChunk,
    ClockProbe,
    ClockReply,
    Credit,
    CreditedFeedback,
    EpisodeEvent,
    LearningSummary,
    Message,
    Observation,
    Said,
    TeacherNotice,
    TeacherStats,
    TeachingStats,
    Utterance,
)
from protocol.schema import ProtocolError
from protocol.vocabulary import Meaning, Vocabulary, VocabularyError, load_vocabulary

__all__ = [
    "ACTION_NAMES",
    "MAX_PAYLOAD_BYTES",
    "MESSAGE_TYPES",
    "ROBOT_TOPICS",
    "SCHEMA_VERSION",
    "TEACHER_TOPICS",
    "Action",
    "Alternative",
    "AudioChunk",
    "ClockProbe",
    "ClockReply",
    "Credit",
    "CreditedFeedback",
    "EpisodeEvent",
    "Key",
    "LearningSummary",
    "Meaning",
    "Message",
    "Observation",
    "ProtocolError",
    "Said",
    "TeacherNotice",
    "TeacherStats",
    "TeachingStats",
    "Utterance",
    "Vocabulary",
    "VocabularyError",
    "check_id",
    "decode",
    "encode",
    "load_vocabulary",
    "parse_key",
    "presence_key",
    "robot_key",
    "session_keys",
    "teacher_key",
    "to_wire",
]

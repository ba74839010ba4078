"""Hypothesis strategies for valid messages, derived from the same type hints the codec checks."""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Annotated, Any, Literal, Union

from hypothesis import strategies as st

from voxshape.protocol import (
    MESSAGE_TYPES,
    Action,
    ClockProbe,
    ClockReply,
    CreditedFeedback,
    Message,
    Said,
    Utterance,
)
from voxshape.protocol.messages import ACTION_NAMES, Credit
from voxshape.protocol.schema import Match, Range, Size

ids = st.from_regex(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,20}", fullmatch=True)


def for_type(tp: Any) -> st.SearchStrategy:
    origin = typing.get_origin(tp)
    if origin is Annotated:
        base, *constraints = typing.get_args(tp)
        return _constrained(base, constraints)
    if origin in (Union, types.UnionType):
        (inner,) = [a for a in typing.get_args(tp) if a is not type(None)]
        return st.none() | for_type(inner)
    if origin is Literal:
        return st.sampled_from(typing.get_args(tp))
    if origin is tuple:
        return st.lists(for_type(typing.get_args(tp)[0]), max_size=8).map(tuple)
    if dataclasses.is_dataclass(tp):
        return for_dataclass(tp)
    return _constrained(tp, [])


def _constrained(base: Any, constraints: list) -> st.SearchStrategy:
    rng = next((c for c in constraints if isinstance(c, Range)), None)
    size = next((c for c in constraints if isinstance(c, Size)), Size(max=50))
    match = next((c for c in constraints if isinstance(c, Match)), None)
    if base is float:
        lo, hi = (rng.lo, rng.hi) if rng else (-1e12, 1e12)
        return st.floats(lo, hi, allow_nan=False, allow_infinity=False)
    if base is int:
        lo, hi = (int(rng.lo), int(rng.hi)) if rng else (-(2**53), 2**53)
        return st.integers(lo, hi)
    if base is bool:
        return st.booleans()
    if base is bytes:
        return st.binary(min_size=size.min, max_size=min(size.max, 64))
    if base is str:
        if match is not None:
            return st.from_regex(match.pattern, fullmatch=True)
        return st.text(min_size=size.min, max_size=min(size.max, 40))
    if typing.get_origin(base) is tuple:
        item = for_type(typing.get_args(base)[0])
        return st.lists(item, min_size=size.min, max_size=min(size.max, 12)).map(tuple)
    return for_type(base)


def for_dataclass(cls: type) -> st.SearchStrategy:
    hints = typing.get_type_hints(cls, include_extras=True)
    fields = {f.name: for_type(hints[f.name]) for f in dataclasses.fields(cls)}
    return st.builds(cls, **fields)


def _action(draw: st.DrawFn) -> Action:
    base = draw(for_dataclass(Action))
    discrete = draw(st.none() | st.integers(0, len(ACTION_NAMES) - 1))
    v, omega = draw(st.none() | st.tuples(st.floats(-10, 10), st.floats(-20, 20))) or (None, None)
    if discrete is None and v is None:
        discrete = 0
    return dataclasses.replace(base, discrete=discrete, v=v, omega=omega)


def _feedback(draw: st.DrawFn) -> CreditedFeedback:
    base = draw(for_dataclass(CreditedFeedback))
    raw = draw(st.lists(st.floats(0.0, 1.0), min_size=1, max_size=12))
    total = sum(raw)
    weights = [w / total if total > 1 else w for w in raw]
    credits = tuple(Credit(step=i, weight=min(1.0, w)) for i, w in enumerate(weights))
    if math.fsum(c.weight for c in credits) > 1.0 + 1e-6:
        credits = credits[:1]
    if draw(st.booleans()):
        return dataclasses.replace(
            base,
            kind="reward",
            reward=draw(st.floats(-1e3, 1e3)),
            command=None,
            credits=credits,
            question=None,  # only a command answers a question
        )
    return dataclasses.replace(
        base,
        kind="command",
        reward=None,
        command=draw(st.sampled_from(ACTION_NAMES)),
        credits=credits,
    )


def _utterance(draw: st.DrawFn) -> Utterance:
    base = draw(for_dataclass(Utterance))
    onset, end = sorted((base.onset, base.end))
    return dataclasses.replace(base, onset=onset, end=end)


def _said(draw: st.DrawFn) -> Said:
    base = draw(for_dataclass(Said))
    onset, end = sorted((base.onset, base.end))
    return dataclasses.replace(base, onset=onset, end=end)


def _clock_probe(draw: st.DrawFn) -> ClockProbe:
    base = draw(for_dataclass(ClockProbe))
    if (base.offset is None) != (base.rtt is None):
        base = dataclasses.replace(base, offset=None, rtt=None)
    return base


def _clock_reply(draw: st.DrawFn) -> ClockReply:
    base = draw(for_dataclass(ClockReply))
    t1, t2 = sorted((base.t1, base.t2))
    return dataclasses.replace(base, t1=t1, t2=t2)


def _even_pcm(message: Message) -> Message:
    pcm = getattr(message, "pcm", b"")
    return dataclasses.replace(message, pcm=pcm[: len(pcm) // 2 * 2]) if pcm else message


_CROSS_FIELD = {
    Action: st.composite(_action)(),
    CreditedFeedback: st.composite(_feedback)(),
    Utterance: st.composite(_utterance)(),
    Said: st.composite(_said)(),
    ClockProbe: st.composite(_clock_probe)(),
    ClockReply: st.composite(_clock_reply)(),
}


def messages(cls: type[Message]) -> st.SearchStrategy[Message]:
    """Valid messages of one type, cross-field rules included."""
    if cls in _CROSS_FIELD:
        return _CROSS_FIELD[cls]
    return for_dataclass(cls).map(_even_pcm)


any_message = st.sampled_from(sorted(MESSAGE_TYPES.values(), key=lambda c: c.TYPE)).flatmap(
    messages
)

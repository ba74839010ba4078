"""Field constraints for wire messages, and the strict checker that enforces them.

A message field is declared with a plain type plus constraints in `Annotated`, e.g.
``laser: Annotated[tuple[Meters, ...], Size(max=1081)]``. `checker_for(cls)` compiles a
dataclass's fields once into a function that takes the decoded msgpack map and returns the
dataclass, or raises `ProtocolError` naming the field and the problem. The same checker runs
on encode, so a service can never put a malformed message on the bus.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Annotated, Any, Literal, Union

__all__ = ["Check", "Match", "ProtocolError", "Range", "Size", "checker_for"]

# Floats beyond this cannot be told apart from integers on the wire; ints beyond it are refused.
_MAX_EXACT_INT = 2**53


class ProtocolError(ValueError):
    """A message or key that cannot be accepted. `field` says where, `problem` says what."""

    def __init__(self, field: str, problem: str) -> None:
        self.field = field
        self.problem = problem
        super().__init__(f"{field}: {problem}")


@dataclass(frozen=True)
class Range:
    """Inclusive numeric bounds; also rejects NaN and infinities."""

    lo: float
    hi: float

    def __call__(self, value: float, where: str) -> None:
        if not self.lo <= value <= self.hi:
            raise ProtocolError(where, f"{value!r} is outside [{self.lo:g}, {self.hi:g}]")


@dataclass(frozen=True)
class Size:
    """Bounds on the length of a str, bytes or tuple."""

    max: int
    min: int = 0

    def __call__(self, value: str | bytes | tuple, where: str) -> None:
        n = len(value)
        if n < self.min:
            raise ProtocolError(where, f"has {n} items/characters, at least {self.min} required")
        if n > self.max:
            raise ProtocolError(where, f"has {n} items/characters, at most {self.max} allowed")


@dataclass(frozen=True)
class Match:
    """A str that must match `pattern` in full; `hint` tells the sender what is allowed."""

    pattern: str
    hint: str

    def __call__(self, value: str, where: str) -> None:
        if not re.fullmatch(self.pattern, value):
            raise ProtocolError(where, f"{value!r} is not allowed: {self.hint}")


Check = Callable[[Any, str], Any]
"""Takes a decoded value and its field path; returns the typed value or raises ProtocolError."""


def _describe(value: object) -> str:
    return f"{type(value).__name__} {value!r}"[:80]


def _plain(tp: type) -> Check:
    if tp is bool:

        def check_bool(v: Any, where: str) -> bool:
            if type(v) is not bool:
                raise ProtocolError(where, f"expected a bool, got {_describe(v)}")
            return v

        return check_bool
    if tp is int:

        def check_int(v: Any, where: str) -> int:
            if type(v) is not int:
                raise ProtocolError(where, f"expected an int, got {_describe(v)}")
            if abs(v) > _MAX_EXACT_INT:
                raise ProtocolError(where, f"{v} is beyond +-2**53")
            return v

        return check_int
    if tp is float:

        def check_float(v: Any, where: str) -> float:
            # An int is accepted where a float is expected (other msgpack encoders shorten
            # 1.0 to 1); a bool is not, even though Python calls it an int.
            if type(v) is float:
                if not math.isfinite(v):
                    raise ProtocolError(where, f"{v!r} is not a finite number")
                return v
            if type(v) is int and abs(v) <= _MAX_EXACT_INT:
                return float(v)
            raise ProtocolError(where, f"expected a float, got {_describe(v)}")

        return check_float
    if tp in (str, bytes):

        def check_exact(v: Any, where: str) -> Any:
            if type(v) is not tp:
                raise ProtocolError(where, f"expected {tp.__name__}, got {type(v).__name__}")
            return v

        return check_exact
    if dataclasses.is_dataclass(tp):
        return checker_for(tp)
    raise TypeError(f"no wire checker for type {tp!r}")


def _compile(tp: Any) -> Check:
    origin = typing.get_origin(tp)
    if origin is Annotated:
        base, *constraints = typing.get_args(tp)
        inner = _compile(base)

        def check_annotated(v: Any, where: str) -> Any:
            v = inner(v, where)
            for constraint in constraints:
                constraint(v, where)
            return v

        return check_annotated
    if origin in (Union, types.UnionType):
        options = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(options) != 1:
            raise TypeError(f"only `X | None` unions are supported on the wire, not {tp!r}")
        inner = _compile(options[0])
        return lambda v, where: None if v is None else inner(v, where)
    if origin is Literal:
        choices = typing.get_args(tp)

        def check_literal(v: Any, where: str) -> Any:
            # `type(v) is type(c)` keeps True from passing for 1.
            if not any(v == c and type(v) is type(c) for c in choices):
                raise ProtocolError(where, f"{v!r} is not one of {', '.join(map(repr, choices))}")
            return v

        return check_literal
    if origin is tuple:
        args = typing.get_args(tp)
        if len(args) != 2 or args[1] is not Ellipsis:
            raise TypeError(f"only homogeneous tuple[X, ...] is supported on the wire, not {tp!r}")
        item = _compile(args[0])
        bounds = _float_bounds(args[0])

        def check_tuple(v: Any, where: str) -> tuple:
            # Fast path for sensor arrays: every item a float within bounds. Anything else
            # takes the item-by-item path, which names the first offending index.
            if bounds and type(v) in (tuple, list) and all(type(x) is float for x in v):
                lo, hi = bounds
                if all(lo <= x <= hi for x in v):
                    return tuple(v)
            if type(v) not in (tuple, list):
                raise ProtocolError(where, f"expected an array, got {type(v).__name__}")
            return tuple([item(x, f"{where}[{i}]") for i, x in enumerate(v)])

        return check_tuple
    return _plain(tp)


def _float_bounds(tp: Any) -> tuple[float, float] | None:
    """(lo, hi) if `tp` is exactly Annotated[float, Range(lo, hi)], else None."""
    if typing.get_origin(tp) is not Annotated:
        return None
    base, *constraints = typing.get_args(tp)
    if base is float and len(constraints) == 1 and isinstance(constraints[0], Range):
        return constraints[0].lo, constraints[0].hi
    return None


_checkers: dict[type, Check] = {}


def checker_for(cls: type) -> Check:
    """The strict checker of a dataclass: map in, instance out (cached per class)."""
    if cls in _checkers:
        return _checkers[cls]
    hints = typing.get_type_hints(cls, include_extras=True)
    fields = [(f.name, _compile(hints[f.name])) for f in dataclasses.fields(cls)]
    names = {name for name, _ in fields}
    post_check = getattr(cls, "check", None)

    def check_struct(v: Any, where: str) -> Any:
        if not isinstance(v, Mapping):
            raise ProtocolError(where or cls.__name__, f"expected a map, got {type(v).__name__}")
        prefix = f"{where}." if where else ""
        unknown = [k for k in v if k not in names]
        if unknown:
            raise ProtocolError(f"{prefix}{unknown[0]}", f"unknown field in {cls.__name__}")
        values = {}
        for name, check in fields:
            if name not in v:
                raise ProtocolError(f"{prefix}{name}", f"missing (required by {cls.__name__})")
            values[name] = check(v[name], f"{prefix}{name}")
        instance = cls(**values)
        if post_check is not None:
            post_check(instance)
        return instance

    _checkers[cls] = check_struct
    return check_struct

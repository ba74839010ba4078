"""A service's settings, each written once: a field of a config dataclass with its default,
its help, its flag and its environment variable (LeRobot's config dataclasses made into the
command line, in the small).

    @dataclass(frozen=True)
    class SimOptions:
        rtf: float = option(1.0, "simulated seconds per wall second", env="VOXSHAPE_RTF")

    add_options(parser, SimOptions)               # --rtf RTF  (VOXSHAPE_RTF; default 1)
    options = read_options(SimOptions, args)      # the flag, else the variable, else 1.0

A field made by `option` is set by its flag (and its variable, if it has one) alone; the
other fields of a config dataclass are set by `--set KEY=VALUE` (`add_settings_argument`,
`replaced`), which refuses a field that has a flag of its own: one spelling per setting.
"""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import json
import os
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

OPTION = "voxshape.option"  # the key of a field's metadata that makes it an option
NAMED = "--{name}"  # the default flag: the field's name, dashed
SCALARS: tuple[type, ...] = (str, int, float, Path)
TRUE, FALSE = ("1", "true", "yes", "on"), ("0", "false", "no", "off")


class ConfigError(ValueError):
    """A setting that cannot work; the message names the setting and how to fix it."""


class SettingsError(ConfigError):
    """A `--set KEY=VALUE` that does not fit the configuration."""


@dataclass(frozen=True)
class Option:
    """How a field is given: its `flag` (None: by its variable alone), its variable `env`, a
    `parse` of the text given (of each, for a `repeat`able flag, whose variable is
    comma-separated, and `collect` makes the field's value of them), `choices`, and `show`,
    what the help says of the default."""

    help: str
    flag: str | None = NAMED
    env: str | None = None
    parse: Callable[[Any], Any] | None = None
    choices: tuple[str, ...] | None = None
    repeat: bool = False
    collect: Callable[[list], Any] = tuple
    metavar: str | None = None
    show: str | None = None
    group: str | None = None  # an argument group of its own (its title)


def option(
    default: Any = dataclasses.MISSING,
    help: str = "",
    *,
    default_factory: Callable[[], Any] | Any = dataclasses.MISSING,
    **how: Any,
) -> Any:
    """A dataclass field that is a setting of the command line; `how` as Option's fields."""
    return dataclasses.field(
        default=default, default_factory=default_factory, metadata={OPTION: Option(help, **how)}
    )


def option_of(field: dataclasses.Field) -> Option | None:
    return field.metadata.get(OPTION)


def _kind(hint: Any) -> tuple[type | None, tuple[str, ...] | None]:
    """The type a text is parsed into (None: no scalar) and the choices of a Literal; an
    optional (`X | None`) is its X."""
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        return _kind(args[0]) if len(args) == 1 else (None, None)
    if typing.get_origin(hint) is typing.Literal:
        return str, tuple(str(a) for a in args)
    return (hint if hint in (*SCALARS, bool) else None), None


def options(cls: type) -> list[tuple[dataclasses.Field, Option, type | None, tuple | None]]:
    """The option fields of a config dataclass: (field, option, kind, choices)."""
    hints = typing.get_type_hints(cls)
    found = []
    for field in dataclasses.fields(cls):
        how = option_of(field)
        if how is None:
            continue
        hint = hints[field.name]
        if how.repeat and typing.get_origin(hint) in (tuple, list, frozenset, set):
            hint = typing.get_args(hint)[0]  # a repeatable flag's items
        kind, choices = _kind(hint)
        if kind is None and how.parse is None:
            raise TypeError(f"{cls.__name__}.{field.name}: its type needs a parse= of the text")
        found.append((field, how, kind, how.choices or choices))
    return found


def flag_of(field: dataclasses.Field) -> str | None:
    how = option_of(field)
    return how.flag.format(name=field.name.replace("_", "-")) if how and how.flag else None


def add_options(
    parser: argparse.ArgumentParser,
    cls: type,
    title: str | None = None,
    flags: Mapping[str, str] | None = None,
) -> None:
    """A flag for each option field of `cls` (in an argument group `title`, if given);
    `flags` renames some (field name -> flag). Each flag's default is None: `read_options`
    tells a flag given from one that was not, and then takes the variable or the default."""
    defaults = cls()
    taken = {action.dest for action in parser._actions}
    for field, how, kind, choices in options(cls):
        flag = (flags or {}).get(field.name) or flag_of(field)
        if flag is None:
            continue
        if field.name in taken:
            raise ValueError(f"{cls.__name__}.{field.name}: the command has that setting twice")
        extra: dict[str, Any] = {"action": "store_true"} if kind is bool else {}
        if how.repeat:
            extra["action"] = "append"
        elif choices:
            extra["choices"] = choices
        if kind is not bool and not (choices and not how.repeat):
            extra["metavar"] = how.metavar or flag.lstrip("-").replace("-", "_").upper()
        shown = _help(how, getattr(defaults, field.name))
        group = _group(parser, how.group or title)
        group.add_argument(flag, dest=field.name, default=None, help=shown, **extra)


def _group(parser: argparse.ArgumentParser, title: str | None) -> Any:
    """The parser's argument group of that title (made on first use); the parser itself for
    no title."""
    if title is None:
        return parser
    known = (g for g in parser._action_groups if g.title == title)
    return next(known, None) or parser.add_argument_group(title)


def _help(how: Option, default: Any) -> str:
    shown = how.show if how.show is not None else _shown(default)
    env = f"{how.env}, comma-separated" if how.env and how.repeat else how.env
    repeat = "repeatable" if how.repeat else ""
    notes = [n for n in (repeat, env, f"default {shown}" if shown else "") if n]
    text = f"{how.help} ({'; '.join(notes)})" if notes else how.help
    return text.replace("%", "%%")


def _shown(default: Any) -> str:
    if default is None or default is False or default == () or default == {}:
        return ""
    if isinstance(default, tuple | list | frozenset):
        return ",".join(map(str, default))
    return f"{default:g}" if isinstance(default, float) else str(default)


Config = TypeVar("Config")


def read_options(
    cls: type[Config],
    args: argparse.Namespace | None = None,
    env: Mapping[str, str] = os.environ,
    base: Config | None = None,
) -> Config:
    """`base` (by default `cls()`) with each option field given a flag's value, else its
    variable's (an empty variable is unset); ConfigError names a value that does not parse,
    and the flag or variable it came from."""
    changes = {}
    for field, how, kind, choices in options(cls):
        given = getattr(args, field.name, None) if how.flag is not None else None
        if given is not None and given != []:
            where = flag_of(field) or field.name
        elif how.env is not None and env.get(how.env):
            given, where = env[how.env], how.env
        else:
            continue
        changes[field.name] = _parsed(given, how, kind, choices, where)
    try:
        return dataclasses.replace(base if base is not None else cls(), **changes)
    except ConfigError:
        raise
    except ValueError as e:  # the dataclass refuses the combination
        raise ConfigError(str(e)) from None


def _parsed(given: Any, how: Option, kind: type | None, choices: tuple | None, where: str) -> Any:
    """A flag's value or a variable's text as the field's type: a repeatable one's items
    each parsed, then collected."""
    if how.repeat:
        items = given.split(",") if isinstance(given, str) else given  # a variable: a list
        parsed = [_one(i.strip(), how, kind, choices, where) for i in items if i.strip()]
        return how.collect(parsed)
    return _one(given, how, kind, choices, where)


def _one(given: Any, how: Option, kind: type | None, choices: tuple | None, where: str) -> Any:
    said = f"{where}={given!r}" if where.isupper() else f"{where} {given!r}"
    if kind is bool:
        if isinstance(given, bool):
            return given
        if given.strip().lower() not in (*TRUE, *FALSE):
            raise ConfigError(f"{said}: say true or false")
        return given.strip().lower() in TRUE
    if choices and given not in choices:
        raise ConfigError(f"{said} is not one of {', '.join(choices)}")
    try:
        if how.parse is not None:
            return how.parse(given)
        assert kind is not None
        return kind(given)
    except ValueError as e:  # ConfigError and ProtocolError too: they say what is wrong
        why = str(e) if how.parse is not None else f"not a valid {kind.__name__}"
        raise ConfigError(f"{said}: {why}") from None


def add_settings_argument(
    parser: argparse.ArgumentParser, source: str, example: str, flag: str = "--set"
) -> None:
    """`flag KEY=VALUE`, repeatable: a field of the config dataclass in `source`."""
    parser.add_argument(
        flag,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help=f"a setting of {source} (repeatable), e.g. {example}",
    )


def replaced(
    config: Config, settings: list[str], flag: str = "--set", taken: type | None = None
) -> Config:
    """The dataclass `config` with `KEY=VALUE` settings applied (values in JSON: 0.1, true,
    "replacing", [1.0, 2.5]; KEY.FIELD=VALUE sets a field of a nested dataclass); raises
    SettingsError naming an unknown key, a value of the wrong type, one the dataclass
    refuses or a field that has a flag of its own, in `config` or among the option fields of
    the dataclass `taken` (`flag` names the option in the message)."""
    items = []
    for setting in settings:
        key, sep, raw = setting.partition("=")
        items.append((setting, key if sep else "", raw))  # no "=": no key, refused below
    flagged = {f.name: flag_of(f) for f in dataclasses.fields(taken)} if taken else {}
    return _replaced(config, items, flag, {k: v for k, v in flagged.items() if v})


def _replaced(
    config: Config, items: list[tuple[str, str, str]], flag: str, flagged: dict[str, str]
) -> Config:
    """`replaced` over (the setting as given, KEY, VALUE) items."""
    fields = {f.name: f for f in dataclasses.fields(config)}
    changes = {}
    for setting, key, raw in items:
        outer, dot, inner = key.partition(".")
        if dot and outer in fields and dataclasses.is_dataclass(getattr(config, outer)):
            nested = changes.get(outer, getattr(config, outer))
            changes[outer] = _replaced(nested, [(setting, inner, raw)], flag, {})
            continue
        if key not in fields:
            raise SettingsError(f"{flag} {setting!r}: {unknown_key(key, sorted(fields))}")
        own = flagged.get(key) or flag_of(fields[key])
        if own is not None:
            raise SettingsError(f"{flag} {setting!r}: {key} has a flag of its own: {own}")
        changes[key] = _value(config, fields[key], setting, raw, flag)
    try:
        return dataclasses.replace(config, **changes)
    except ValueError as e:
        raise SettingsError(f"{flag}: {e}") from None


def unknown_key(key: str, known: list[str]) -> str:
    """What to say of a KEY that is none of `known`: the close ones first ("lookahead":
    did you mean lookahead_s?), then them all."""
    if not key:
        return f"use KEY=VALUE with KEY one of {', '.join(known)}"
    close = difflib.get_close_matches(key, known, n=3, cutoff=0.6)
    close += [k for k in known if k.startswith(key) and k not in close][: 3 - len(close)]
    meant = f"did you mean {' or '.join(close)}? " if close else ""
    return f"no setting {key!r}; {meant}KEY is one of {', '.join(known)}"


def _value(config: object, field: dataclasses.Field, setting: str, raw: str, flag: str) -> Any:
    """VALUE (JSON, or a bare word for a string) as the type of `config`'s `field`."""
    key = field.name
    try:
        value = json.loads(raw)
    except json.JSONDecodeError:
        value = raw  # a bare word: a string
    current = getattr(config, key)
    if dataclasses.is_dataclass(current):
        names = ", ".join(f.name for f in dataclasses.fields(current))
        raise SettingsError(
            f"{flag} {setting!r}: {key} is not a single value; set its fields as "
            f"{key}.FIELD=VALUE, FIELD one of {names}"
        )
    try:
        return checked(typing.get_type_hints(type(config))[key], value, current, key)
    except ValueError as e:
        raise SettingsError(f"{flag} {setting!r}: {e}") from None


def checked(hint: Any, value: Any, default: Any, name: str) -> Any:
    """`value` (as JSON gives it) as a value of type `hint`: a Literal's choices, a number's
    kind, a tuple's items and a dict's keys (every one of the `default`'s, no other) and
    values checked; ValueError names `name`, the value and what is allowed."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is typing.Literal:
        if value not in args:
            allowed = ", ".join(map(str, args))
            raise ValueError(f"{name} {json.dumps(value)} is not one of {allowed}")
        return value
    if isinstance(hint, types.UnionType) or origin is typing.Union:
        if value is None and type(None) in args:
            return None
        arms = [a for a in args if a is not type(None)]
        return checked(arms[0] if len(arms) == 1 else Any, value, default, name)
    if origin in (tuple, list) and isinstance(value, list | tuple):
        return _items(origin, args, value, default, name)
    if origin is dict and isinstance(value, dict):
        return _entries(args, value, default, name)
    return _scalar(hint, value, default, name)


def _scalar(hint: Any, value: Any, default: Any, name: str) -> Any:
    """A number, text, path or flag as `hint` (int is a float too); other hints: a value of
    the default's type."""
    if hint is float and type(value) in (int, float):
        return float(value)
    if hint is Path and isinstance(value, str):
        return Path(value)
    want = hint if hint in (str, int, bool) else type(default)
    if hint is Any or type(value) is want:
        return value
    like = f", like {json.dumps(default, default=str)}" if default is not None else ""
    kind = getattr(hint, "__name__", None) or want.__name__
    article = "an" if kind[0] in "aeiou" else "a"
    raise ValueError(f"{name} takes {article} {kind}{like}, not {json.dumps(value, default=str)}")


def _items(origin: Any, args: tuple, value: list | tuple, default: Any, name: str) -> Any:
    """A tuple's (or list's) items, each of its type: tuple[X, ...] any number of them."""
    if origin is tuple and args and args[-1] is not Ellipsis:
        if len(value) != len(args):
            raise ValueError(f"{name} takes {len(args)} values, not {json.dumps(value)}")
        kinds = list(args)
    else:
        kinds = [args[0] if args else Any] * len(value)
    pairs = enumerate(zip(kinds, value, strict=True))
    items = [checked(k, v, None, f"{name}[{i}]") for i, (k, v) in pairs]
    return tuple(items) if origin is tuple else items


def _entries(args: tuple, value: dict, default: Any, name: str) -> dict:
    """A dict with every key of the default's (when it has some) and no other, each value of
    its type."""
    if isinstance(default, dict) and default:
        missing = [k for k in default if k not in value]
        unknown = [k for k in value if k not in default]
        if missing or unknown:
            said = f"missing {', '.join(missing)}" if missing else f"not {', '.join(unknown)}"
            raise ValueError(f"{name} takes every key of {', '.join(default)} ({said})")
    kind = args[1] if len(args) == 2 else Any
    return {k: checked(kind, v, None, f"{name}[{k}]") for k, v in value.items()}


def record(config: object) -> dict[str, Any]:
    """A config dataclass as JSON-ready data (nested ones as dicts, tuples as lists, paths as
    text): what `from_record` reads back."""
    return json.loads(json.dumps(dataclasses.asdict(config), default=str))  # type: ignore[call-overload]


def from_record(cls: type[Config], data: Mapping[str, Any], where: str) -> Config:
    """The config dataclass `cls` that `record` wrote as `data`, each value checked as a
    `--set` is; a field the record lacks (written before it existed) keeps its default, and
    one since removed (named in the class's RETIRED) is passed over. SettingsError names
    `where` the record came from and the field that does not fit."""
    defaults, hints = cls(), typing.get_type_hints(cls)
    fields = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    retired = set(getattr(cls, "RETIRED", ()))
    unknown = sorted(set(data) - fields - retired)
    if unknown:
        raise SettingsError(f"{where}: no setting {', '.join(unknown)} in {cls.__name__}")
    changes = {}
    for key, value in data.items():
        if key in retired:
            continue
        current = getattr(defaults, key)
        try:
            if dataclasses.is_dataclass(current):
                changes[key] = from_record(type(current), value, f"{where} {key}")
            else:
                changes[key] = checked(hints[key], value, current, key)
        except (ValueError, TypeError) as e:
            raise SettingsError(f"{where}: {e}") from None
    try:
        return dataclasses.replace(defaults, **changes)
    except ValueError as e:
        raise SettingsError(f"{where}: {e}") from None


SETTINGS_FILE = "settings.json"  # a run's effective settings, by section: {"learner": {...}}


def write_settings(folder: Path, section: str, config: object) -> Path:
    """Records `config` as `section` of `folder`'s settings.json (the other sections kept),
    atomically: the settings a run or an experiment ran with."""
    path = folder / SETTINGS_FILE
    folder.mkdir(parents=True, exist_ok=True)
    sections = _sections(path)
    sections[section] = record(config)
    part = path.with_name(f".{SETTINGS_FILE}.{os.getpid()}")
    part.write_text(json.dumps(sections, indent=1) + "\n", "utf-8")
    part.replace(path)
    return path


def read_settings(folder: Path, section: str, cls: type[Config]) -> Config | None:
    """The `cls` recorded as `section` of `folder`'s settings.json; None if none is (a run
    made before runs recorded it). SettingsError names a record that does not fit."""
    data = _sections(folder / SETTINGS_FILE).get(section)
    return None if data is None else from_record(cls, data, f"{folder / SETTINGS_FILE} {section}")


def _sections(path: Path) -> dict[str, Any]:
    try:
        sections = json.loads(path.read_text("utf-8"))
    except FileNotFoundError:
        return {}
    except (OSError, ValueError) as e:
        raise SettingsError(f"{path}: unreadable ({e}); move it aside to write it anew") from None
    if not isinstance(sections, dict):
        raise SettingsError(f"{path}: not an object of sections; move it aside")
    return sections

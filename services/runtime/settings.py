"""A service's settings from the command line: `--set KEY=VALUE` over its config dataclass, so
every default lives in the dataclass and every field can be set the same way."""

from __future__ import annotations

import argparse
import dataclasses
import json
from typing import TypeVar


class SettingsError(ValueError):
    """A `--set KEY=VALUE` that does not fit the configuration."""


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


Config = TypeVar("Config")


def replaced(config: Config, settings: list[str], flag: str = "--set") -> Config:
    """The dataclass `config` with `KEY=VALUE` settings applied (values in JSON: 0.1, true,
    "replacing", [1.0, 2.5]; KEY.FIELD=VALUE sets a field of a nested dataclass); raises
    SettingsError naming an unknown key, a value of the wrong type or one the dataclass
    refuses (`flag` names the option in the message)."""
    items = []
    for setting in settings:
        key, sep, raw = setting.partition("=")
        items.append((setting, key if sep else "", raw))  # no "=": no key, refused below
    return _replaced(config, items, flag)


def _replaced(config: Config, items: list[tuple[str, str, str]], flag: str) -> Config:
    """`replaced` over (the setting as given, KEY, VALUE) items."""
    fields = {f.name: f for f in dataclasses.fields(config)}
    changes = {}
    for setting, key, raw in items:
        outer, dot, inner = key.partition(".")
        if dot and outer in fields and dataclasses.is_dataclass(getattr(config, outer)):
            nested = changes.get(outer, getattr(config, outer))
            changes[outer] = _replaced(nested, [(setting, inner, raw)], flag)
            continue
        if key not in fields:
            raise SettingsError(
                f"{flag} {setting!r}: use KEY=VALUE with KEY one of {', '.join(sorted(fields))}"
            )
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
        if isinstance(current, tuple) and isinstance(value, list):
            value = tuple(value)
        if type(value) is int and "float" in str(fields[key].type):  # float, float | None
            value = float(value)
        ok = (
            type(value) is type(current)
            or (current is None and isinstance(value, float))
            or (value is None and "None" in str(fields[key].type))
        )
        if not ok:
            raise SettingsError(
                f"{flag} {setting!r}: {key} takes a {type(current).__name__}, "
                f"like {json.dumps(current)}"
            )
        changes[key] = value
    try:
        return dataclasses.replace(config, **changes)
    except ValueError as e:
        raise SettingsError(f"{flag}: {e}") from None

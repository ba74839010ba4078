"""A run's settings on record: runs/<session>/settings.json, one section per process (its
node id: `learner`, `sim`...), each holding the config dataclasses it ran with by class name:

    {"learner": {"LearnerOptions": {...}, "LearnerConfig": {...}}, "sim": {...}, ...}

Every service writes its section as it starts (`write_settings`), so a report or a replay
judges a run by what it ran with (`read_settings`), not by today's defaults. The services of a
session start together: each rewrites the file under a lock, keeping the others' sections.
An experiment's folder holds one too (its learner's and its simulated teacher's).
"""

from __future__ import annotations

import dataclasses
import fcntl
import json
import os
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

from voxshape.runtime.config import BusConfig
from voxshape.runtime.settings import ConfigError, SettingsError, checked

RUNS = Path("runs")  # runs/<session>/: a session's run, in the folder its services run in
SETTINGS_FILE = "settings.json"
LOCK_FILE = ".settings.lock"  # held while one process rewrites settings.json

Config = TypeVar("Config")


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


def write_settings(folder: Path, section: str, *configs: object) -> Path:
    """Records `configs` (config dataclasses, each under its class's name) as `section` of
    `folder`'s settings.json, the other sections kept: read, changed and replaced whole under
    a lock, so that processes writing at once keep each other's."""
    path = folder / SETTINGS_FILE
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / LOCK_FILE, "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        sections = _sections(path)
        sections[section] = {type(c).__name__: record(c) for c in configs}
        part = path.with_name(f".{SETTINGS_FILE}.{os.getpid()}")
        part.write_text(json.dumps(sections, indent=1) + "\n", "utf-8")
        part.replace(path)
    return path


def read_settings(folder: Path, section: str, cls: type[Config]) -> Config | None:
    """The `cls` recorded in `section` of `folder`'s settings.json; None if none is (a run
    made before runs recorded it). A section written before sections held classes by name
    is that one config. SettingsError names a record that does not fit."""
    data = _sections(folder / SETTINGS_FILE).get(section)
    if isinstance(data, dict) and data and all(key[:1].isupper() for key in data):
        data = data.get(cls.__name__)  # classes by name (config fields are lower case)
    where = f"{folder / SETTINGS_FILE} {section}"
    return None if data is None else from_record(cls, data, where)


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


def write_run_settings(bus: BusConfig, role: str, *configs: object) -> Path:
    """Records a service's `configs` as its section (its node id, else its role) of its run's
    runs/<session>/settings.json; ConfigError if it cannot be written."""
    try:
        return write_settings(RUNS / bus.session, bus.node or role, *configs)
    except OSError as e:
        raise ConfigError(f"cannot record its settings in {RUNS / bus.session}: {e}") from None

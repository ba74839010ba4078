"""A session's run directory and the configuration the logger writes beside its event log.

    runs/<session>/events.msgpack     every sample of the bus (eventlog.py)
    runs/<session>/session.json       the session's configuration: map, settings, versions
    runs/<session>/recording.rrd      the rerun recording (live, or re-rendered by replay)
    runs/<session>/logger-stats.json  what the logger received and wrote to the event log
    runs/<session>/recording-stats.json   what the recording drew, and the scans it thinned
    runs/<session>/report/            pictures and summary of `voxshape report`
    runs/<session>/learner-<robot>.npz    each robot's learner checkpoint (the learner's own)
    runs/<session>/session.lock       held by the live session's launcher (hold_run)
    runs/<session>/launcher.json      its launcher's pid, router and services' pids, while
                                      it runs (voxshape/launcher/record.py)

`voxshape up` and `voxshape demo` start each run of a session in an empty runs/<session>/:
an earlier run there is kept aside as runs/<session>.<its start time>/ (unless --resume).

The map lives in session.json as the text of its TOML file, so a replay or a report draws the
map the session ran on even if the file changed or is on another machine.
"""

from __future__ import annotations

import fcntl
import json
import os
import platform
import socket
import time
import tomllib
from dataclasses import asdict, dataclass, field
from importlib import metadata
from pathlib import Path
from typing import IO, Any

from voxshape.runtime import ConfigError
from voxshape.world.maps import Map, MapError, load_map, parse_map

RUNS = Path("runs")
SESSION_FILE = "session.json"
EVENTS_FILE = "events.msgpack"
RECORDING_FILE = "recording.rrd"
RECEIVER_STATS_FILE = "logger-stats.json"
RECORDING_STATS_FILE = "recording-stats.json"
REPORT_DIR = "report"
LOCK_FILE = "session.lock"  # held by the launcher of the session the run belongs to
DEFAULT_VIEWER_PORT = 9876  # where the logger serves the live recording to viewers
SECRET_WORDS = ("PASSWORD", "SECRET", "TOKEN", "KEY")


class RunError(ValueError):
    """A run directory or its configuration that cannot be used; says what to do."""


@dataclass(frozen=True)
class RunDir:
    path: Path

    @classmethod
    def for_session(cls, session: str, root: Path = RUNS) -> RunDir:
        return cls(root / session)

    @classmethod
    def existing(cls, path: Path | str) -> RunDir:
        """A run directory that must hold an event log; RunError says what is wrong."""
        path = Path(path)
        if not path.exists():
            raise RunError(
                f"no run directory {path}: the logger writes runs/<session>/ in the directory "
                "it runs in (`ls runs/` lists the sessions recorded here)"
            )
        if path.is_file() and path.name == EVENTS_FILE:
            path = path.parent
        run = cls(path)
        if not run.events.is_file():
            raise RunError(
                f"{path} holds no {EVENTS_FILE}: not a run directory of the logger "
                "(was `voxshape logger` running during the session?)"
            )
        return run

    @property
    def events(self) -> Path:
        return self.path / EVENTS_FILE

    @property
    def session_file(self) -> Path:
        return self.path / SESSION_FILE

    @property
    def recording(self) -> Path:
        return self.path / RECORDING_FILE

    @property
    def receiver_stats(self) -> Path:
        return self.path / RECEIVER_STATS_FILE

    @property
    def recording_stats(self) -> Path:
        return self.path / RECORDING_STATS_FILE

    @property
    def report(self) -> Path:
        return self.path / REPORT_DIR


@dataclass(frozen=True)
class SessionInfo:
    """What the session ran with, as far as the logger knows it."""

    session: str
    started: float
    map_name: str
    map_source: str
    map_toml: str
    settings: dict[str, Any] = field(default_factory=dict)
    environment: dict[str, str] = field(default_factory=dict)
    versions: dict[str, str] = field(default_factory=dict)
    host: str = ""

    def world(self) -> Map:
        """The map, parsed from the text recorded at the session's start."""
        try:
            return parse_map(tomllib.loads(self.map_toml), self.map_source)
        except (tomllib.TOMLDecodeError, MapError) as e:
            raise RunError(f"the map recorded in {SESSION_FILE} is unusable: {e}") from None


def describe_session(session: str, task: str, settings: dict[str, Any]) -> SessionInfo:
    """The configuration of a session starting now with map `task` (number or file)."""
    m = load_map(task)
    return SessionInfo(
        session=session,
        started=time.time(),
        map_name=m.name,
        map_source=m.source,
        map_toml=Path(m.source).read_text(encoding="utf-8"),
        settings=settings,
        environment={
            k: v
            for k, v in sorted(os.environ.items())
            if k.startswith("VOXSHAPE_") and not any(w in k for w in SECRET_WORDS)
        },
        versions={
            name: _version(name) for name in ("voxshape", "rerun-sdk", "eclipse-zenoh", "msgpack")
        }
        | {"python": platform.python_version()},
        host=platform.node(),
    )


def _version(package: str) -> str:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "unknown"


def write_session_info(run: RunDir, info: SessionInfo) -> SessionInfo:
    """Writes session.json, or keeps the one a previous logger of this session wrote (it
    must name the same map). Returns the info in effect."""
    if run.session_file.is_file():
        existing = read_session_info(run)
        if existing.map_toml != info.map_toml:
            raise RunError(
                f"{run.session_file} records map {existing.map_name!r} ({existing.map_source}) "
                f"but this logger was given {info.map_name!r} ({info.map_source}): give the "
                "logger the simulator's --task, or use a new session id"
            )
        return existing
    run.path.mkdir(parents=True, exist_ok=True)
    write_json_atomically(run.session_file, asdict(info))
    return info


def read_session_info(run: RunDir) -> SessionInfo:
    if not run.session_file.is_file():
        raise RunError(
            f"{run.session_file} is missing, so the map is unknown: give it with --task "
            "(the simulator's task number or map file)"
        )
    try:
        data = json.loads(run.session_file.read_text(encoding="utf-8"))
        return SessionInfo(**data)
    except (json.JSONDecodeError, TypeError) as e:
        raise RunError(
            f"{run.session_file} is not a session configuration ({e}); give the map with --task"
        ) from None


def session_map(run: RunDir, task: str | None = None) -> Map:
    """The map of a recorded session: `task` if given, else the one in session.json."""
    if task is not None:
        return load_map(task)
    return read_session_info(run).world()


def holds_a_run(path: Path) -> bool:
    """Whether `path` holds anything of an earlier run (its lock aside)."""
    return path.exists() and any(p.name != LOCK_FILE for p in path.iterdir())


def hold_run(path: Path, holder: str) -> IO[str]:
    """Takes `path` (runs/<session>/) for this process's session while it lives: a lock on
    its session.lock, which the kernel lets go when the process ends, however it ends. The
    file to keep open; RunError naming the folder, who holds it and the way out if a live
    session does."""
    path.mkdir(parents=True, exist_ok=True)
    lock = (path / LOCK_FILE).open("a+", encoding="utf-8")
    try:
        fcntl.flock(lock.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.seek(0)
        other = lock.read().strip() or "another process"
        lock.close()
        raise RunError(
            f"{path} belongs to a session that is running ({other}): stop that one first, "
            f"or give this one its own name and folder with --session NAME"
        ) from None
    lock.seek(0)
    lock.truncate()
    lock.write(f"{holder}, pid {os.getpid()}, since {time.strftime('%Y-%m-%d %H:%M:%S')}\n")
    lock.flush()
    return lock


def keep_earlier_run(path: Path) -> Path | None:
    """Moves an earlier run out of `path` (runs/<session>/, or an experiment's folder) to a
    sibling named by when it started, e.g. runs/<session>.YYYY-MM-DDTHH-MM-SS/, so that a new
    run starts empty there; returns where it went, or None if `path` held nothing. Nothing
    is deleted."""
    if not holds_a_run(path) if path.is_dir() else not path.exists():
        return None
    try:
        started = read_session_info(RunDir(path)).started
    except RunError:  # no session.json (no logger ran): its oldest file tells
        started = min((p.stat().st_mtime for p in path.rglob("*")), default=None)
    stamp = time.strftime("%Y-%m-%dT%H-%M-%S", time.localtime(started or path.stat().st_mtime))
    kept = path.with_name(f"{path.name}.{stamp}")
    for n in range(2, 1000):
        if not kept.exists():
            break
        kept = path.with_name(f"{path.name}.{stamp}-{n}")
    path.rename(kept)
    return kept


def write_json_atomically(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    tmp.replace(path)


def viewer_port(value: str | None = None) -> int:
    """The port the live recording is served on (VOXSHAPE_VIEWER_PORT, default 9876)."""
    raw = value if value is not None else os.environ.get("VOXSHAPE_VIEWER_PORT", "")
    if raw in ("", None):
        return DEFAULT_VIEWER_PORT
    try:
        port = int(raw)
    except ValueError:
        raise ConfigError(f"viewer port {raw!r} is not a number (VOXSHAPE_VIEWER_PORT)") from None
    if not 0 <= port <= 65535:
        raise ConfigError(f"viewer port {port} is outside 0-65535 (0 turns serving off)")
    return port


def port_is_free(bind: str, port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind((bind, port))
        except OSError:
            return False
    return True

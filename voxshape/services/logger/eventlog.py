"""The durable event log of a session: every sample of the bus, appended as it arrives.

A file of msgpack objects, one after another (`runs/<session>/events.msgpack`):

    {"format": "voxshape-events", "version": 1, "session": "...", "created": 1.7e9}  header
    [received, key, kind, payload]                                                   a record
    [received, key, kind, payload]
    ...

- `received`: the logger's wall clock (Unix seconds) when the sample arrived;
- `key`: the zenoh key expression it arrived on, e.g. `voxshape/s1/robot/r1/obs`;
- `kind`: "put" (a message, or a node's presence token appearing), "delete" (a presence
  token vanishing) or "gap" (messages on `key` the logger missed and could not get back);
- `payload`: the raw bytes as they crossed the bus (empty for presence tokens); of a gap,
  msgpack `{"missed": count, "source": "<zenoh id>/<entity id>"}` (`pack_gap`).

Records are raw, so a message type this build does not know is kept as faithfully as a known
one. Appending only adds to a buffer in memory (a few microseconds, no disk access); the
writer's owner flushes it often, so a killed logger loses at most the last flush interval. A
crash can leave an incomplete last record: readers report it and stop before it, and a writer
reopening the file cuts it off before appending. Anything else that is not a record is
damage, reported with its byte offset.

Pure: files and msgpack only, no bus.
"""

from __future__ import annotations

import fcntl
import math
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Literal, NamedTuple

import msgpack

from voxshape.protocol import MAX_PAYLOAD_BYTES

FORMAT = "voxshape-events"
VERSION = 1
KINDS = ("put", "delete", "gap")
# No record can be longer than this: a payload at the protocol's limit plus a key and a time.
MAX_RECORD_BYTES = MAX_PAYLOAD_BYTES + 1024
READ_CHUNK_BYTES = 1 << 20

Kind = Literal["put", "delete", "gap"]


class EventLogError(ValueError):
    """An event log that cannot be read or appended to; the message names the file, the
    problem and the fix."""


class EventRecord(NamedTuple):
    received: float  # logger wall clock, Unix seconds
    key: str
    kind: Kind
    payload: bytes


@dataclass(frozen=True)
class Header:
    session: str
    created: float


def pack_record(record: EventRecord) -> bytes:
    return msgpack.packb(
        [record.received, record.key, record.kind, record.payload], use_bin_type=True
    )


def pack_gap(missed: int, source: str) -> bytes:
    """A gap record's payload: how many messages of one publisher the logger missed."""
    return msgpack.packb({"missed": missed, "source": source}, use_bin_type=True)


def _pack_header(header: Header) -> bytes:
    return msgpack.packb(
        {
            "format": FORMAT,
            "version": VERSION,
            "session": header.session,
            "created": header.created,
        },
        use_bin_type=True,
    )


def _repair_hint(path: Path, offset: int) -> str:
    return (
        f"The file is damaged from byte {offset} on; keep everything before it with "
        f"`truncate -s {offset} {path}` (or move the file away to start a new log)"
    )


def _header(obj: object, path: Path) -> Header:
    if (
        not isinstance(obj, dict)
        or obj.get("format") != FORMAT
        or not isinstance(obj.get("session"), str)
        or not isinstance(obj.get("created"), int | float)
    ):
        raise EventLogError(
            f"{path} is not a voxshape event log (it does not start with a "
            f"{FORMAT!r} header). Give the events.msgpack of a run directory."
        )
    if obj.get("version") != VERSION:
        raise EventLogError(
            f"{path} is an event log of version {obj.get('version')!r}; this build reads "
            f"version {VERSION}. Use the voxshape version that wrote it."
        )
    return Header(obj["session"], float(obj["created"]))


def _record(obj: object, path: Path, index: int, offset: int) -> EventRecord:
    problem = None
    if not isinstance(obj, list | tuple) or len(obj) != 4:
        problem = f"expected [received, key, kind, payload], got {type(obj).__name__}"
    else:
        received, key, kind, payload = obj
        if not isinstance(received, float | int) or not math.isfinite(received):
            problem = f"receive time {received!r} is not a number"
        elif not isinstance(key, str) or not key:
            problem = f"key {key!r} is not a non-empty string"
        elif kind not in KINDS:
            problem = f"kind {kind!r} is not one of {', '.join(KINDS)}"
        elif not isinstance(payload, bytes):
            problem = f"payload is {type(payload).__name__}, not bytes"
        else:
            return EventRecord(float(received), key, kind, payload)
    raise EventLogError(
        f"{path}: record {index} at byte {offset}: {problem}. " + _repair_hint(path, offset)
    )


class EventLogReader:
    """Reads an event log from its start, in pieces as it grows (`poll`) or all at once
    (`read_events`). Keeps track of where the last complete record ends."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise EventLogError(
                f"no event log at {self.path}: the logger writes runs/<session>/events.msgpack "
                "in the directory it runs in (is the run directory right?)"
            )
        self._file: BinaryIO = self.path.open("rb")
        self._unpacker = msgpack.Unpacker(
            raw=False,
            strict_map_key=True,
            max_buffer_size=4 * READ_CHUNK_BYTES,
            ext_hook=self._no_extension,
        )
        self.header: Header | None = None
        self.records = 0  # complete records read so far
        self.end = 0  # byte offset just after the last complete object (header or record)
        self._fed = 0  # bytes read from the file so far

    def _no_extension(self, code: int, data: bytes) -> None:
        raise EventLogError(
            f"{self.path}: msgpack extension type {code} near byte {self.end}. "
            + _repair_hint(self.path, self.end)
        )

    @property
    def pending(self) -> int:
        """Bytes after the last complete record: an incomplete record still being written,
        or left behind by a killed writer."""
        return self._fed - self.end

    def poll(self) -> list[EventRecord]:
        """The complete records in the next megabyte of the file: [] only at its end (for now,
        if it grows). Raises EventLogError on damage."""
        data = self._file.read(READ_CHUNK_BYTES)
        if data:
            self._unpacker.feed(data)
            self._fed += len(data)
        out = self._drain()
        if self.pending > MAX_RECORD_BYTES:
            raise EventLogError(
                f"{self.path}: {self.pending} bytes from byte {self.end} do not form a record "
                f"(none is longer than {MAX_RECORD_BYTES}). " + _repair_hint(self.path, self.end)
            )
        return out

    def _drain(self) -> list[EventRecord]:
        out = []
        while True:
            try:
                obj = next(self._unpacker)
            except StopIteration:
                return out
            except EventLogError:
                raise
            except (ValueError, msgpack.UnpackException) as e:  # FormatError, StackError...
                raise EventLogError(
                    f"{self.path}: not msgpack near byte {self.end} ({type(e).__name__}). "
                    + _repair_hint(self.path, self.end)
                ) from None
            if self.header is None:
                self.header = _header(obj, self.path)
            else:
                out.append(_record(obj, self.path, self.records, self.end))
                self.records += 1
            self.end = self._unpacker.tell()

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> EventLogReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class EventLog:
    """A whole event log as read: header, records, and the incomplete tail a crash left."""

    path: Path
    header: Header
    records: list[EventRecord]
    incomplete_tail: int  # bytes after the last complete record

    def describe_tail(self) -> str | None:
        """A sentence about an incomplete tail (for warnings), None when there is none."""
        if not self.incomplete_tail:
            return None
        return (
            f"{self.path} ends with {self.incomplete_tail} bytes of an incomplete record (the "
            f"logger stopped while writing it: killed?); using the {len(self.records)} "
            "complete records before it"
        )


def read_events(path: Path | str) -> EventLog:
    """Every complete record of an event log; raises EventLogError naming damage and fix."""
    with EventLogReader(path) as reader:
        records = []
        while batch := reader.poll():
            records += batch
        if reader.header is None:
            raise EventLogError(
                f"{reader.path} is empty or shorter than its header: nothing was logged "
                "(the logger stopped at once?)"
            )
        return EventLog(reader.path, reader.header, records, reader.pending)


class EventLogWriter:
    """Appends records to an event log. `append` may be called from any thread (zenoh's
    callbacks) and never touches the disk: it adds the record to an in-memory buffer. The
    owner calls `flush` every fraction of a second (one write of everything buffered; a killed
    process loses what is still buffered) and `sync` to fsync.

    Opening an existing log checks its header belongs to `session` and cuts off an incomplete
    last record left by a killed writer (`repaired_bytes` says how much)."""

    def __init__(self, path: Path | str, session: str) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.repaired_bytes = 0
        self.records = 0
        self.bytes = 0
        self._file = self.path.open("ab", buffering=0)
        try:  # one writer per log: a second logger in the same directory would interleave
            fcntl.flock(self._file.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._file.close()
            raise EventLogError(
                f"{self.path} is being written by another logger of this session: stop it, "
                "or run this one in another directory"
            ) from None
        try:
            if os.fstat(self._file.fileno()).st_size > 0:
                self.header = self._reopen(session)
            else:
                self.header = Header(session, time.time())
                self._file.write(_pack_header(self.header))
        except BaseException:
            self._file.close()
            raise
        self._buffer = bytearray()
        self._buffer_lock = threading.Lock()  # appenders vs the flusher taking the buffer
        self._write_lock = threading.Lock()  # one flusher at a time

    def _reopen(self, session: str) -> Header:
        with EventLogReader(self.path) as reader:
            while reader.poll():
                pass
            if reader.header is None:
                raise EventLogError(f"{self.path} holds no complete header: move it away")
            if reader.header.session != session:
                raise EventLogError(
                    f"{self.path} is the event log of session {reader.header.session!r}, "
                    f"not {session!r}: use that session id or another run directory"
                )
            end, self.repaired_bytes = reader.end, reader.pending
            self.records = reader.records
        if self.repaired_bytes:
            os.ftruncate(self._file.fileno(), end)  # appends go to the new end
        return reader.header

    def append(self, record: EventRecord) -> int:
        """Buffers one record (no disk access); returns its size in bytes."""
        data = pack_record(record)
        with self._buffer_lock:
            self._buffer += data
            self.records += 1
            self.bytes += len(data)
        return len(data)

    @property
    def buffered(self) -> int:
        """Bytes appended but not yet written to the file."""
        return len(self._buffer)

    def flush(self) -> None:
        """Writes everything buffered to the file (the OS has it: it survives this process)."""
        with self._write_lock:
            with self._buffer_lock:
                data, self._buffer = self._buffer, bytearray()
            view = memoryview(data)
            while view:
                view = view[self._file.write(view) :]

    def sync(self) -> None:
        """Flushes and asks the OS to put the file on disk (survives a power cut)."""
        self.flush()
        with self._write_lock:
            os.fsync(self._file.fileno())

    def close(self) -> None:
        if not self._file.closed:
            self.sync()
            self._file.close()

    def __enter__(self) -> EventLogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

"""The durable event log: append and read back, a killed writer's incomplete tail, damage
named with its offset and fix, following a growing log; and decoding records of any type."""

from __future__ import annotations

import msgpack
import pytest

from voxshape.protocol import encode, robot_key
from voxshape.protocol.examples import example_messages
from voxshape.services.logger.decoding import (
    Known,
    PresenceChange,
    Rejected,
    Unknown,
    decode_record,
)
from voxshape.services.logger.eventlog import (
    EventLogError,
    EventLogReader,
    EventLogWriter,
    EventRecord,
    pack_record,
    read_events,
)
from voxshape.services.logger.run import RunDir, RunError


def records(session: str, n: int) -> list[EventRecord]:
    examples = example_messages(session)
    picked = (examples[i % len(examples)] for i in range(n))
    return [EventRecord(1.7e9 + i, key, "put", encode(m)) for i, (key, m) in enumerate(picked)]


def test_records_come_back_as_written(tmp_path):
    path = tmp_path / "events.msgpack"
    written = records("s1", 50)
    with EventLogWriter(path, "s1") as writer:
        for record in written:
            writer.append(record)
        writer.append(EventRecord(1.8e9, "voxshape/s1/presence/sim/sim", "delete", b""))
    log = read_events(path)
    assert log.header.session == "s1"
    assert log.records[:50] == written
    assert log.records[50].kind == "delete" and log.incomplete_tail == 0
    assert log.describe_tail() is None


def test_an_incomplete_last_record_is_reported_and_cut_off_on_reopen(tmp_path):
    path = tmp_path / "events.msgpack"
    with EventLogWriter(path, "s1") as writer:
        for record in records("s1", 10):
            writer.append(record)
    whole = path.stat().st_size
    observation = next(r for r in records("s1", 10) if r.key.endswith("/obs"))
    with path.open("ab") as f:  # a killed writer: half of a record
        f.write(pack_record(observation)[:700])
    log = read_events(path)
    assert len(log.records) == 10 and log.incomplete_tail == 700
    assert "700 bytes of an incomplete record" in log.describe_tail()
    with EventLogWriter(path, "s1") as writer:  # a restarted logger appends after the cut
        assert writer.repaired_bytes == 700 and writer.records == 10
        writer.append(records("s1", 2)[1])
    assert path.stat().st_size > whole
    assert len(read_events(path).records) == 11


def test_damage_is_named_with_its_offset_and_the_fix(tmp_path):
    path = tmp_path / "events.msgpack"
    with EventLogWriter(path, "s1") as writer:
        for record in records("s1", 3):
            writer.append(record)
    good = path.stat().st_size
    with path.open("ab") as f:
        f.write(msgpack.packb({"not": "a record"}))
        f.write(pack_record(records("s1", 1)[0]))
    with pytest.raises(EventLogError) as e:
        read_events(path)
    assert f"record 3 at byte {good}" in str(e.value)
    assert f"truncate -s {good} {path}" in str(e.value)


def test_foreign_files_wrong_sessions_and_second_writers_are_refused(tmp_path):
    path = tmp_path / "events.msgpack"
    path.write_bytes(b"\x00\x01 not an event log at all")
    with pytest.raises(EventLogError, match="is not a voxshape event log"):
        read_events(path)
    with pytest.raises(EventLogError, match="no event log at"):
        read_events(tmp_path / "missing.msgpack")
    other = tmp_path / "other.msgpack"
    EventLogWriter(other, "s1").close()
    with pytest.raises(EventLogError, match="event log of session 's1', not 's2'"):
        EventLogWriter(other, "s2")
    with EventLogWriter(other, "s1"), pytest.raises(EventLogError, match="another logger"):
        EventLogWriter(other, "s1")  # two loggers in one directory would interleave records


def test_a_reader_follows_a_growing_log_record_by_record(tmp_path):
    path = tmp_path / "events.msgpack"
    written = records("s1", 30)
    with EventLogWriter(path, "s1") as writer, EventLogReader(path) as reader:
        assert reader.poll() == []
        seen = []
        for i in range(3):
            for record in written[10 * i : 10 * i + 10]:
                writer.append(record)
            writer.flush()
            seen += reader.poll()
            assert len(seen) == 10 * (i + 1) and reader.pending == 0
    assert seen == written


def test_run_directories_say_what_is_missing(tmp_path):
    with pytest.raises(RunError, match=r"no run directory .*ls runs/"):
        RunDir.existing(tmp_path / "runs" / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(RunError, match=r"holds no events\.msgpack"):
        RunDir.existing(tmp_path / "empty")


def test_records_decode_as_known_unknown_presence_or_rejected():
    key = robot_key("s1", "r1", "obs")
    obs = dict(example_messages("s1"))[key]
    known = decode_record(EventRecord(1.0, key, "put", encode(obs)))
    assert isinstance(known, Known) and known.message == obs and known.key.owner == "r1"

    # a new message type from a newer build, on a new topic: kept and shown, not rejected
    newer = msgpack.packb({"schema": 1, "type": "arbiter_stats", "dropped": 3, "robot": "r1"})
    unknown = decode_record(EventRecord(1.0, "voxshape/s1/robot/r1/arbiter", "put", newer))
    assert isinstance(unknown, Unknown) and unknown.type_name == "arbiter_stats"
    assert unknown.fields == {"dropped": 3, "robot": "r1"}

    # a known type on a topic this build does not list is still decoded by its type
    moved = decode_record(EventRecord(1.0, "voxshape/s1/robot/r1/obs2", "put", encode(obs)))
    assert isinstance(moved, Known) and moved.key is None

    bad = decode_record(EventRecord(1.0, key, "put", b"\xc1garbage"))
    assert isinstance(bad, Rejected) and "not a msgpack message" in bad.problem
    wrong = decode_record(EventRecord(1.0, robot_key("s1", "r1", "action"), "put", encode(obs)))
    assert isinstance(wrong, Rejected) and "'observation' where 'action' was expected" in (
        wrong.problem
    )

    gone = decode_record(EventRecord(1.0, "voxshape/s1/presence/sim/sim-1", "delete", b""))
    assert gone == PresenceChange(gone.record, "sim", "sim-1", False)

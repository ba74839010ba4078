"""`voxshape logger`: records a whole session.

Its flows are its `logger` row of voxshape/protocol/dataflow.py
(`voxshape dataflow --docstring logger`).

Every message, raw (known types or not), and the presence tokens of nodes joining and
leaving (presence/**).

Writes:  runs/<session>/events.msgpack           the durable event log (eventlog.py)
         runs/<session>/session.json             map and settings (run.py)
         runs/<session>/recording.rrd            the rerun recording, by a child process
         runs/<session>/logger-stats.json        what was received and written

Two processes, so that recording never slows the session down:
- this one only appends raw samples to the event log's memory buffer (a few microseconds; no
  decoding, no drawing) and writes the buffer out every `--flush-every` seconds. zenoh hands
  the samples over through a FIFO channel, so its receiving thread never waits for Python or
  the disk. Publishers never wait for it either (voxshape/protocol/dataflow.py DELIVERY): what it
  cannot take while slow or stopped is dropped for it, and fetched back from the
  publishers' caches when it runs again; what they no longer keep is a gap record;
- a child (renderer.py), `voxshape replay RUN --follow`, at a lower CPU priority, follows the
  event log and draws it with rerun (recording.py), serving viewers on `--serve-port`. When it
  falls behind it draws fewer scans (counted); the event log is never thinned.
"""

from __future__ import annotations

import argparse
import subprocess
import threading
import time
from collections import Counter
from dataclasses import dataclass
from typing import Any

import zenoh
from zenoh.ext import AdvancedSubscriber, Miss

from voxshape.protocol import MAX_PAYLOAD_BYTES
from voxshape.runtime import (
    BusConfig,
    ConfigError,
    Node,
    Tick,
    add_bus_arguments,
    bus_config,
    fields,
)
from voxshape.runtime.flows import recovering_subscriber
from voxshape.runtime.settings import add_options, option, read_options
from voxshape.runtime.settings_file import write_run_settings
from voxshape.services.logger.eventlog import EventLogError, EventLogWriter, EventRecord, pack_gap
from voxshape.services.logger.renderer import start_renderer, stop_renderer
from voxshape.services.logger.replay import ScanThinning, add_thinning_arguments
from voxshape.services.logger.run import (
    DEFAULT_VIEWER_PORT,
    RunDir,
    RunError,
    describe_session,
    viewer_port,
    write_json_atomically,
    write_session_info,
)
from voxshape.world.maps import task_option

# Samples zenoh may hold for this process before it makes the router wait (~20 s of a session)
RECEIVE_QUEUE = 50_000


class Receiver:
    """Appends each raw sample to the event log and counts it, and marks what was missed for
    good as a gap, nothing else."""

    def __init__(self, writer: EventLogWriter, everything: str) -> None:
        self.writer = writer
        self.everything = everything  # the session's key expression: a gap of unknown source
        self.counts: Counter[str] = Counter()
        self.record_seconds = 0.0
        self.record_max = 0.0
        self.keys: dict[tuple[str, int], str] = {}  # a kept output's id -> its key

    def record(self, sample: zenoh.Sample) -> None:
        t0 = time.perf_counter()
        try:
            key = str(sample.key_expr)
            payload = sample.payload.to_bytes()
            if len(payload) > MAX_PAYLOAD_BYTES:  # not a message by the protocol's definition
                self.counts["dropped.oversized"] += 1
                return
            kind = "put" if sample.kind == zenoh.SampleKind.PUT else "delete"
            self.writer.append(EventRecord(time.time(), key, kind, payload))
            source = sample.source_info
            if source is not None:  # a kept output: a gap of it names its key
                self.keys[(str(source.source_id.zid), source.source_id.eid)] = key
            parts = key.split("/")
            self.counts["presence" if "presence" in parts[2:3] else f"received.{parts[-1]}"] += 1
        except Exception:  # a bad sample must not end the receiving thread
            self.counts["errors"] += 1
        finally:
            took = time.perf_counter() - t0
            self.record_seconds += took
            self.record_max = max(self.record_max, took)

    def missed(self, miss: Miss) -> None:
        """A kept output's messages the logger could not get back (it was stopped for longer
        than they are kept): a gap record in their place, and counted."""
        try:
            source = (str(miss.source.zid), miss.source.eid)
            key = self.keys.get(source, self.everything)
            payload = pack_gap(miss.nb, f"{source[0]}/{source[1]}")
            self.writer.append(EventRecord(time.time(), key, "gap", payload))
            self.counts[f"missed.{key.split('/')[-1]}"] += miss.nb
        except Exception:  # never end zenoh's callback thread
            self.counts["errors"] += 1

    def drain(self, subscriber: AdvancedSubscriber) -> None:
        """Records what a FIFO-channel subscriber receives, until it is undeclared."""
        for sample in subscriber:
            self.record(sample)

    def stats(self) -> dict:
        counts = dict.copy(self.counts)  # atomic under the GIL while the callback adds keys
        n = sum(v for k, v in counts.items() if k.startswith(("received.", "presence")))
        return {
            "records": self.writer.records,
            "bytes": self.writer.bytes,
            "buffered_bytes": self.writer.buffered,  # not yet written to the file
            "repaired_bytes": self.writer.repaired_bytes,
            "record_us_mean": round(1e6 * self.record_seconds / n, 1) if n else 0.0,
            "record_us_max": round(1e6 * self.record_max, 1),
            **counts,
        }


@dataclass(frozen=True)
class LoggerOptions:
    """`voxshape logger`'s settings (and ScanThinning's, which its renderer takes)."""

    task: str = task_option("to draw")
    flush_every: float = option(
        0.05, "seconds between flushes of the event log (at most this much is lost if killed)"
    )
    fsync_every: float = option(
        1.0, "seconds between fsyncs (what a power cut can lose); 0: only at the end"
    )
    serve_port: str | None = option(
        None,
        "serve the live recording to viewers on this port (0: do not serve)",
        env="VOXSHAPE_VIEWER_PORT",
        show=str(DEFAULT_VIEWER_PORT),
    )
    serve_bind: str = option("127.0.0.1", "address to serve viewers on", env="VOXSHAPE_VIEWER_BIND")
    no_recording: bool = option(False, "write only the event log (no rerun)")
    render_nice: int = option(
        5, "CPU niceness of the rendering process (higher: yields more to the session)"
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    add_options(parser, LoggerOptions)
    add_thinning_arguments(parser)


def run(args: argparse.Namespace) -> int:
    options = read_options(LoggerOptions, args)
    thinning = read_options(ScanThinning, args)
    if options.flush_every <= 0 or options.fsync_every < 0:
        raise ConfigError("--flush-every must be > 0 seconds and --fsync-every >= 0")
    bus = bus_config("logger", args)
    port = viewer_port(options.serve_port)
    write_run_settings(bus, "logger", options, thinning)
    run_dir = RunDir.for_session(bus.session)
    settings = _settings(options, bus, port)
    with Node("logger", bus) as node:  # present at once (launchers wait for it), then set up
        writer = _open_event_log(node, run_dir, bus.session, options.task, settings)
        receiver = Receiver(writer, node.everything)
        # Recovering what kept outputs dropped for it while it was stopped or slow (they never
        # wait for it); nothing older on joining (a restarted logger would log it twice).
        samples = recovering_subscriber(
            node.zenoh, node.everything, zenoh.handlers.FifoChannel(RECEIVE_QUEUE), 0
        )
        gaps = samples.sample_miss_listener(receiver.missed)
        drainer = threading.Thread(
            target=receiver.drain, args=(samples,), name="event-log", daemon=True
        )
        drainer.start()
        presence = node.zenoh.liveliness().declare_subscriber(  # rare: a callback will do
            node.presences, receiver.record, history=True
        )
        renderer = (
            None
            if options.no_recording
            else start_renderer(
                run_dir, bus.session, (options.serve_bind, port), thinning, options.render_nice
            )
        )
        node.log.info(
            "logging",
            extra=fields(
                events=run_dir.events,
                recording="no" if renderer is None else run_dir.recording,
                renderer_pid=renderer.pid if renderer else "-",
                serving=settings["serve"] or "no",
            ),
        )
        code = _flush_until_stopped(node, options, writer, receiver, renderer, run_dir)
        gaps.undeclare()
        samples.undeclare()  # the drainer records what was queued, then ends
        drainer.join(10)
        presence.undeclare()
        if not _close_event_log(node, writer):
            code = 1
        _save_stats(node, receiver, run_dir)
        if renderer is not None:
            stop_renderer(node, renderer)
    return code


def _settings(options: LoggerOptions, bus: BusConfig, port: int) -> dict[str, Any]:
    """The logger's settings, as session.json records them."""
    serving = port and not options.no_recording
    return {
        "task": options.task,
        "flush_every": options.flush_every,
        "fsync_every": options.fsync_every,
        "serve": f"{options.serve_bind}:{port}" if serving else None,
        "bus": {"mode": bus.mode, "connect": list(bus.connect), "listen": list(bus.listen)},
    }


def _open_event_log(
    node: Node, run_dir: RunDir, session: str, task: str, settings: dict[str, Any]
) -> EventLogWriter:
    """Writes session.json and opens the event log, cutting off what a killed logger left."""
    try:
        write_session_info(run_dir, describe_session(session, task, settings))
        writer = EventLogWriter(run_dir.events, session)
    except EventLogError as e:
        raise RunError(str(e)) from None
    if writer.repaired_bytes:
        node.log.warning(
            "cut off an incomplete last record a killed logger left",
            extra=fields(file=writer.path, bytes=writer.repaired_bytes),
        )
    return writer


def _flush_until_stopped(
    node: Node,
    options: LoggerOptions,
    writer: EventLogWriter,
    receiver: Receiver,
    renderer: subprocess.Popen | None,
    run_dir: RunDir,
) -> int:
    """Every tick: writes the event log out (and syncs it every --fsync-every), reports a dead
    renderer once and saves the stats. 1 when the event log cannot be written, else 0."""
    last_sync = last_stats = time.monotonic()
    renderer_reported = False
    for event in node.events(tick=options.flush_every):
        if not isinstance(event, Tick):
            continue
        now = time.monotonic()
        try:
            writer.flush()
            if options.fsync_every and now - last_sync >= options.fsync_every:
                writer.sync()
                last_sync = now
        except OSError as e:  # disk full, file gone
            node.log.error(f"cannot write the event log {writer.path}: {e}; stopping")
            return 1
        if renderer is not None and renderer.poll() is not None and not renderer_reported:
            renderer_reported = True
            node.log.error(
                "the recording process died; the event log goes on. Re-render the "
                f"recording afterwards with `voxshape replay {run_dir.path}`",
                extra=fields(exit_code=renderer.returncode),
            )
        if now - last_stats >= 1.0:
            _save_stats(node, receiver, run_dir)
            last_stats = now
    return 0


def _close_event_log(node: Node, writer: EventLogWriter) -> bool:
    """Writes out the rest of the event log; False (and logged) if it cannot."""
    try:
        writer.close()
    except OSError as e:
        node.log.error(f"cannot write the event log {writer.path}: {e}")
        return False
    return True


def _save_stats(node: Node, receiver: Receiver, run_dir: RunDir) -> None:
    stats = receiver.stats()
    write_json_atomically(run_dir.receiver_stats, stats)
    for k, v in stats.items():
        if isinstance(v, int):
            node.counters[k] = v

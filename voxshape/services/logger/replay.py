"""`voxshape replay RUN_DIR`: renders a session's event log into a rerun recording.

The logger itself renders this way: it starts `voxshape replay RUN_DIR --follow` beside it,
which reads the event log as it grows and draws each record with the same `Recorder`. So a
replay yields the same data as the live recording, unless the live one fell behind and thinned
its scans (counted in recording-stats.json).

    voxshape replay runs/s1                     -> runs/s1/replay.rrd
    voxshape replay runs/s1 --output x.rrd
    voxshape replay runs/s1 --follow --serve-port 9876    live: follow the log, serve viewers
"""

from __future__ import annotations

import argparse
import logging
import os
import select
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from voxshape.protocol import Observation
from voxshape.runtime import ConfigError, fields
from voxshape.runtime.settings import add_options, option, read_options
from voxshape.services.logger.decoding import Known, decode_record
from voxshape.services.logger.eventlog import EventLogError, EventLogReader, EventRecord
from voxshape.services.logger.run import (
    RunDir,
    RunError,
    port_is_free,
    read_session_info,
    session_map,
    viewer_port,
    write_json_atomically,
)
from voxshape.world.maps import Map

if TYPE_CHECKING:  # rerun takes half a second to import: only commands that draw load it
    import rerun as rr

    from voxshape.services.logger.recording import Recorder

log = logging.getLogger("voxshape.services.logger")

FLUSH_ROWS = 5000  # send buffered rows at least this often
FOLLOW_POLL_S = 0.02  # how often a follower looks for new records
FOLLOW_FLUSH_S = 0.1  # how often a follower sends what it buffered (viewer latency)
STATS_EVERY_S = 1.0
WAIT_FOR_LOG_S = 10.0


@dataclass
class ScanThinning:
    """When the renderer is more than `lag_limit` seconds behind the bus, it draws only one
    observation's scan and footprint in `keep_one_in`."""

    lag_limit: float = option(
        0.5,
        "seconds behind the bus after which the recording draws fewer scans",
        flag="--thin-after",
    )
    keep_one_in: int = option(10, "when thinning", flag="--keep-one-scan-in")
    _behind: int = 0

    def detail(self, lag: float) -> bool:
        if lag <= self.lag_limit:
            return True
        self._behind += 1
        return self._behind % self.keep_one_in == 1


# What the live server keeps for viewers that join late; rerun drops the oldest beyond it.
# The default, 25% of the machine's memory, let the renderer grow ~37 MB a minute with four
# robots at real time for hours (benchmarks/soak.py): this bounds it.
VIEWER_HISTORY = "256MiB"


def open_stream(
    recording_id: str,
    output: Path,
    world: Map | None,
    serve: tuple[str, int] | None = None,
    footer: bool = True,
) -> tuple[rr.RecordingStream, str | None]:
    """A recording stream writing `output` and, if `serve` = (bind, port), serving viewers
    (late ones get the history). Returns the stream and the URL viewers connect to.
    `footer`: end the file with rerun's index of its chunks (faster to open), which the stream
    holds in memory until it closes: a follower sends ~10 chunks a second per entity, and that
    index grew by ~27 MB a minute with four robots (benchmarks/soak.py), so it writes none."""
    import rerun as rr

    from voxshape.services.logger.scene import APPLICATION, blueprint

    stream = rr.RecordingStream(APPLICATION, recording_id=recording_id)
    sinks: list = [rr.FileSink(str(output), write_footer=footer)]
    url = None
    if serve is not None:
        bind, port = serve
        if port_is_free(bind, port):
            server = rr.GrpcServerSink(bind, port, server_memory_limit=VIEWER_HISTORY)
            sinks.append(server)
            url = server.uri
        else:
            log.warning(
                "not serving the live recording: the port is taken (another logger or viewer?);"
                " choose another with --serve-port or VOXSHAPE_VIEWER_PORT",
                extra=fields(bind=bind, port=port),
            )
    output.parent.mkdir(parents=True, exist_ok=True)
    stream.set_sinks(*sinks, default_blueprint=blueprint(world))
    return stream, url


def close_stream(stream: rr.RecordingStream) -> None:
    """Flushes and closes every sink (a one-shot replay's .rrd gets its footer)."""
    try:
        stream.flush()
    finally:
        stream.disconnect()


def render(records: Iterable[EventRecord], recorder: Recorder) -> int:
    """Draws every record in full (a replay); returns how many."""
    n = 0
    for record in records:
        recorder.record(decode_record(record))
        n += 1
        if recorder.pending_rows >= FLUSH_ROWS:
            recorder.flush()
    recorder.flush()
    return n


def follow(
    reader: EventLogReader,
    recorder: Recorder,
    thinning: ScanThinning,
    should_stop: Callable[[], bool],
    on_stats: Callable[[dict], None] | None = None,
) -> dict:
    """Draws records as the event log grows, until `should_stop()`; then draws what is left
    (the writer has stopped) and returns the statistics."""
    started = time.monotonic()
    last_flush = last_stats = started
    max_lag = 0.0
    while True:
        stopping = should_stop()
        batch = reader.poll()
        now = time.time()
        for record in batch:
            decoded = decode_record(record)
            detail = True
            if isinstance(decoded, Known) and isinstance(decoded.message, Observation):
                lag = now - record.received  # behind the bus by this much
                max_lag = max(max_lag, lag)
                detail = thinning.detail(lag)
            recorder.record(decoded, detail=detail)
        mono = time.monotonic()
        if recorder.pending_rows >= FLUSH_ROWS or (mono - last_flush >= FOLLOW_FLUSH_S):
            recorder.flush()
            last_flush = mono
        stats = {
            **recorder.counters,
            "max_lag_s": round(max_lag, 3),  # drawing an observation, after it arrived
            "seconds": round(mono - started, 3),
            "incomplete_tail_bytes": reader.pending,
        }
        if on_stats is not None and mono - last_stats >= STATS_EVERY_S:
            on_stats(stats)
            last_stats = mono
        if stopping and not batch:
            recorder.flush()
            return stats
        if not batch:
            time.sleep(FOLLOW_POLL_S)


def _closed(fd: int) -> bool:
    """Whether the writer end of pipe `fd` is closed (without blocking)."""
    readable, _, _ = select.select([fd], [], [], 0)
    return bool(readable) and os.read(fd, 4096) == b""


def _wait_for(path: Path, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while not path.is_file() and time.monotonic() < deadline:
        time.sleep(0.05)


# -- the command -----------------------------------------------------------------------------


def add_thinning_arguments(parser: argparse.ArgumentParser) -> None:
    """How a recording that follows a live session keeps up: fewer scans when behind."""
    add_options(parser, ScanThinning)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="the run directory, e.g. runs/<session>")
    parser.add_argument(
        "--output",
        type=Path,
        help="the .rrd to write (default: RUN/replay.rrd; RUN/recording.rrd with --follow)",
    )
    parser.add_argument("--task", help="draw this map (default: the one in RUN/session.json)")
    parser.add_argument(
        "--follow",
        action="store_true",
        help="keep reading as the event log grows (what the logger runs), until SIGINT/SIGTERM;"
        " then draw the rest and close the recording",
    )
    parser.add_argument(
        "--serve-port",
        default=None,
        help="also serve the recording to viewers on this port (0: no; default: not serving)",
    )
    parser.add_argument("--serve-bind", default="127.0.0.1", help="address to serve on")
    add_thinning_arguments(parser)
    parser.add_argument("--recording-id", help=argparse.SUPPRESS)
    parser.add_argument(
        "--until-stdin-closes",
        action="store_true",
        help=argparse.SUPPRESS,  # the logger's renderer: stops when the logger closes the pipe
    )


def run(args: argparse.Namespace) -> int:
    run_dir = RunDir(args.run)
    if args.follow:
        _wait_for(run_dir.events, WAIT_FOR_LOG_S)
    run_dir = RunDir.existing(args.run)
    world = session_map(run_dir, args.task)
    try:
        session = read_session_info(run_dir).session
    except RunError:
        session = run_dir.path.name
    output = args.output or (run_dir.recording if args.follow else run_dir.path / "replay.rrd")
    recording_id = args.recording_id or (session if args.follow else f"{session}-replay")
    port = viewer_port(args.serve_port) if args.serve_port is not None else 0
    thinning = read_options(ScanThinning, args)
    if thinning.keep_one_in < 1 or thinning.lag_limit < 0:
        raise ConfigError("--keep-one-scan-in must be >= 1 and --thin-after >= 0")
    from voxshape.services.logger.recording import Recorder

    stream, url = open_stream(
        recording_id,
        output,
        world,
        (args.serve_bind, port) if port else None,
        footer=not args.follow,
    )
    recorder = Recorder(stream, world)
    recorder.start()
    try:
        with EventLogReader(run_dir.events) as reader:
            if args.follow:
                stats = _follow(args, thinning, run_dir, reader, recorder, output, url)
            else:
                t0 = time.perf_counter()
                n = render((r for batch in iter(reader.poll, []) for r in batch), recorder)
                took = time.perf_counter() - t0
                stats = {**recorder.counters, "seconds": round(took, 3)}
                if reader.pending:
                    log.warning(
                        f"{reader.path} ends with {reader.pending} bytes of an incomplete "
                        "record (the logger stopped while writing it: killed?); replayed the "
                        "complete records before it"
                    )
                log.info(
                    "replayed",
                    extra=fields(records=n, output=output, seconds=f"{took:.2f}"),
                )
    except EventLogError as e:
        raise RunError(str(e)) from None
    finally:
        close_stream(stream)
    if args.follow:
        write_json_atomically(run_dir.recording_stats, stats)
    else:
        print(f"{output}: {stats.get('records', 0)} records in {stats['seconds']} s")
    return 0


def _follow(
    args: argparse.Namespace,
    thinning: ScanThinning,
    run_dir: RunDir,
    reader: EventLogReader,
    recorder: Recorder,
    output: Path,
    url: str | None,
) -> dict:
    stop = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        stop.set()

    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    signal.signal(signal.SIGTERM, on_signal)
    # Under a logger, Ctrl-C reaches both: the logger closes the event log, then the pipe.
    signal.signal(signal.SIGINT, signal.SIG_IGN if args.until_stdin_closes else on_signal)

    def should_stop() -> bool:
        if args.until_stdin_closes and not stop.is_set() and _closed(sys.stdin.fileno()):
            stop.set()  # the logger stopped (or died): the event log is complete
        return stop.is_set()

    log.info(
        "rendering",
        extra=fields(events=run_dir.events, recording=output, serving=url or "no"),
    )
    try:
        stats = follow(
            reader,
            recorder,
            thinning,
            should_stop,
            on_stats=lambda s: write_json_atomically(run_dir.recording_stats, s),
        )
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    log.info("recording closed", extra=fields(**{k: stats[k] for k in sorted(stats)}))
    return stats

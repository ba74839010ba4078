"""The logger's rendering child: `voxshape replay RUN --follow` at a lower CPU priority, which
follows the event log and draws it with rerun; started with the logger, and told to finish
(its stdin closed) once the event log is complete."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from collections.abc import Mapping

from voxshape.runtime import Node, fields
from voxshape.services.logger.replay import ScanThinning
from voxshape.services.logger.run import RunDir

RENDERER_STOP_S = 8.0  # then the renderer finishes on its own (it notices the logger is gone)
# A follower writes no footer (replay.open_stream says why), of which rerun warns at every
# start, in raw colour codes that read like an error: that one warning is left out, rerun's
# others kept. Rerun reads RUST_LOG when it is imported, so it is set for the child.
QUIET_RERUN = "warn,re_log_encoding::rrd::file_sink=error"


def renderer_environment(environ: Mapping[str, str]) -> dict[str, str]:
    """The renderer's variables: these, with rerun's footer warning left out (a RUST_LOG of
    the user's own is theirs)."""
    return {"RUST_LOG": QUIET_RERUN, **environ}


def start_renderer(
    run_dir: RunDir, session: str, serve: tuple[str, int], thinning: ScanThinning, nice: int
) -> subprocess.Popen:
    """`voxshape replay` following `run_dir`, serving viewers on `serve` (address, port; 0:
    not), thinning as the logger says, at CPU niceness `nice` when this process may set it."""
    command = [
        sys.executable,
        "-m",
        "voxshape",
        "replay",
        str(run_dir.path),
        "--follow",
        "--until-stdin-closes",
        "--recording-id",
        session,
        "--serve-port",
        str(serve[1]),
        "--serve-bind",
        serve[0],
        "--thin-after",
        str(thinning.lag_limit),
        "--keep-one-scan-in",
        str(thinning.keep_one_in),
    ]
    # Its stdin is a pipe from here: closed when the event log is complete, or by the kernel
    # if this process dies; either way the renderer draws the rest and closes the recording.
    renderer = subprocess.Popen(
        command, stdin=subprocess.PIPE, env=renderer_environment(os.environ)
    )
    with contextlib.suppress(OSError):  # not allowed here: it runs at normal priority
        os.setpriority(os.PRIO_PROCESS, renderer.pid, nice)
    return renderer


def stop_renderer(node: Node, renderer: subprocess.Popen) -> None:
    """Lets the renderer draw the rest of the (now closed) event log and close the .rrd."""
    renderer.stdin.close()
    try:
        renderer.wait(RENDERER_STOP_S)
    except subprocess.TimeoutExpired:
        node.log.warning(
            "the recording is still catching up; it finishes on its own",
            extra=fields(renderer_pid=renderer.pid),
        )

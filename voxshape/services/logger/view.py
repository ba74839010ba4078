"""`voxshape view [TARGET]`: look at a session with rerun's viewer.

TARGET is a run directory (its recording.rrd), an .rrd file, or a `rerun+http://` URL; by
default the live recording the logger serves (127.0.0.1:VOXSHAPE_VIEWER_PORT, 9876). Late
joiners see the history: the logger's server keeps it.

With a display (DISPLAY or WAYLAND_DISPLAY), the native viewer opens; without one, or with
--web, the web viewer is served on localhost only and its URL printed. Runs until Ctrl-C.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import shutil
import signal
import socket
import subprocess
from pathlib import Path
from urllib.parse import quote

from voxshape.runtime import ConfigError
from voxshape.services.logger.run import RunDir, port_is_free, viewer_port

URL_SCHEMES = ("rerun://", "rerun+http://", "rerun+https://")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "target",
        nargs="?",
        help="run directory, .rrd file or rerun+http:// URL (default: the live logger)",
    )
    parser.add_argument("--web", action="store_true", help="web viewer even with a display")
    parser.add_argument("--web-port", type=int, default=9090, help="web viewer's HTTP port")
    parser.add_argument(
        "--grpc-port",
        type=int,
        default=9877,
        help="port that serves a file to the web viewer (not for live sessions)",
    )
    parser.add_argument(
        "--viewer-port",
        default=None,
        help="the live logger's port (VOXSHAPE_VIEWER_PORT, default 9876)",
    )


def rerun_binary() -> str:
    """The viewer's executable itself (the `rerun` script only wraps it in a child process)."""
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin is not None:
        binary = Path(os.environ.get("RERUN_CLI_PATH") or Path(spec.origin).with_name("rerun"))
        if binary.is_file():
            return str(binary)
    found = shutil.which("rerun")
    if found is None:
        raise ConfigError("the rerun viewer is not installed: pip install 'rerun-sdk>=0.41,<0.42'")
    return found


def resolve_target(target: str | None, live_port: int) -> str:
    """A file to open or a URL to connect to; ConfigError says what is wrong."""
    if target is None:
        url = f"rerun+http://127.0.0.1:{live_port}/proxy"
        with socket.socket() as s:
            s.settimeout(1.0)
            if s.connect_ex(("127.0.0.1", live_port)) != 0:
                raise ConfigError(
                    f"no live recording at {url}: is `voxshape logger` running (it serves on "
                    "VOXSHAPE_VIEWER_PORT)? To look at a recorded session: voxshape view "
                    "runs/<session>"
                )
        return url
    if target.startswith(URL_SCHEMES):
        return target
    path = Path(target)
    if path.is_dir():
        recording = RunDir(path).recording
        if not recording.is_file():
            raise ConfigError(
                f"{path} has no recording.rrd; render one from its event log with "
                f"`voxshape replay {path} --output {recording}`"
            )
        return str(recording)
    if path.is_file():
        return str(path)
    raise ConfigError(f"{target}: no such run directory, file or rerun URL")


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def viewer_command(
    target: str, *, web: bool, web_port: int, grpc_port: int
) -> tuple[list[str], str | None]:
    """The rerun command line, and the URL to print for the web viewer."""
    rerun = rerun_binary()
    if not web:
        return [rerun, target], None
    command = [rerun, "--serve-web", "--bind", "127.0.0.1", "--web-viewer-port", str(web_port)]
    if target.startswith(URL_SCHEMES):
        data_url = target
    else:  # the file is served over gRPC beside the web viewer
        command += ["--port", str(grpc_port)]
        data_url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
    return [*command, target], f"http://127.0.0.1:{web_port}/?url={quote(data_url, safe='')}"


def run(args: argparse.Namespace) -> int:
    target = resolve_target(args.target, viewer_port(args.viewer_port))
    web = args.web or not has_display()
    if web:
        for port in (args.web_port, *(() if target.startswith(URL_SCHEMES) else (args.grpc_port,))):
            if not port_is_free("127.0.0.1", port):
                raise ConfigError(
                    f"port {port} on 127.0.0.1 is taken: choose others with --web-port/--grpc-port"
                )
    command, url = viewer_command(target, web=web, web_port=args.web_port, grpc_port=args.grpc_port)
    if url:
        print(f"web viewer of {target}: {url}  (Ctrl-C stops it)", flush=True)
    else:
        print(f"opening the viewer on {target}", flush=True)
    # Its own process group, so that stopping it stops whatever it started.
    viewer = subprocess.Popen(command, stdin=subprocess.DEVNULL, start_new_session=True)

    def on_term(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, on_term)
    try:
        return viewer.wait()
    except KeyboardInterrupt:
        os.killpg(viewer.pid, signal.SIGTERM)
        try:
            viewer.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(viewer.pid, signal.SIGKILL)
            viewer.wait(5)
        return 0

"""`voxshape`: one command, one subcommand per service or tool."""

from __future__ import annotations

import argparse
import atexit
import contextlib
import faulthandler
import importlib
import io
import os
import signal
import sys
import threading
from collections.abc import Callable
from typing import NoReturn

from voxshape.launcher.topology import TopologyError
from voxshape.protocol import ProtocolError, VocabularyError
from voxshape.runtime import BusError, ConfigError, configure_logging
from voxshape.runtime.processes import end_with_parent
from voxshape.runtime.settings import SettingsError
from voxshape.services.logger.run import RunError
from voxshape.world.maps import MapError

Runner = Callable[[argparse.Namespace], int]
Adder = Callable[[argparse.ArgumentParser], None]

# name -> (help, module, its function adding the arguments, its function running it). A
# command's module is imported only when that command runs: `voxshape teach` does not load
# the simulator or matplotlib.
COMMANDS: dict[str, tuple[str, str, str, str]] = {
    "demo": (
        "run the main job in a local session (no docker, no manual router)",
        "voxshape.lab.demo",
        "add_arguments",
        "run",
    ),
    "up": (
        "start the local session: every service of compose.yaml as its own process",
        "voxshape.launcher",
        "add_up_arguments",
        "run",
    ),
    "router": (
        "run the zenoh router of a session",
        "voxshape.deploy.router",
        "add_arguments",
        "run",
    ),
    "certs": (
        "make a development CA, TLS certificates and passwords for a secured session",
        "voxshape.deploy.certs",
        "add_arguments",
        "run",
    ),
    "sim": (
        "run the simulator: PyBullet world, robots, episodes",
        "voxshape.services.sim.node",
        "add_arguments",
        "run",
    ),
    "ros2": (
        "bring a real ROS 2 robot into the session (rmw_zenoh or zenoh-bridge-ros2dds)",
        "voxshape.services.ros2.node",
        "add_arguments",
        "run",
    ),
    "placed": (
        "say a real robot is back at its start (voxshape ros2 --reset wait waits for it)",
        "voxshape.services.ros2.placed",
        "add_arguments",
        "run",
    ),
    "learner": (
        "run the learner: SARSA(lambda) with dynamic reward shaping",
        "voxshape.services.learner.node",
        "add_arguments",
        "run",
    ),
    "train": (
        "train plain SARSA(lambda) in one process and report convergence",
        "voxshape.lab.experiment.train",
        "add_arguments",
        "run",
    ),
    "map": (
        "draw a task's map (start, goal, optional path and scan) as PNG",
        "voxshape.services.sim.commands",
        "add_map_arguments",
        "map_command",
    ),
    "status": (
        "list the nodes present in a session",
        "voxshape.launcher.tools",
        "add_status_arguments",
        "status",
    ),
    "listen": (
        "print every message of a session, decoded",
        "voxshape.launcher.tools",
        "add_listen_arguments",
        "listen",
    ),
    "dataflow": (
        "print who publishes and subscribes to what (voxshape/protocol/dataflow.py)",
        "voxshape.launcher.tools",
        "add_dataflow_arguments",
        "show_dataflow",
    ),
    "vocabulary": (
        "check a vocabulary file and list its phrases",
        "voxshape.launcher.tools",
        "add_vocabulary_arguments",
        "vocabulary",
    ),
    "logger": (
        "record the session: event log, rerun recording, live viewer server",
        "voxshape.services.logger.node",
        "add_arguments",
        "run",
    ),
    "view": (
        "look at a live or recorded session in rerun's viewer",
        "voxshape.services.logger.view",
        "add_arguments",
        "run",
    ),
    "replay": (
        "re-render a session's recording from its event log",
        "voxshape.services.logger.replay",
        "add_arguments",
        "run",
    ),
    "report": (
        "pictures and a summary of a recorded session",
        "voxshape.lab.report",
        "add_arguments",
        "run",
    ),
    "speech": (
        "run the speech service: teachers' audio (or said text) in, utterances out",
        "voxshape.services.speech.node",
        "add_arguments",
        "run",
    ),
    "teach": (
        "teach a robot: speak, stream WAV files or type words; see what was understood",
        "voxshape.services.teacher.node",
        "add_arguments",
        "run",
    ),
    "web": (
        "serve the teachers' web page: watch a robot, speak or type to it in a browser",
        "voxshape.services.web.node",
        "add_arguments",
        "run",
    ),
    "arbiter": (
        "run the feedback arbiter: utterances in, credited rewards and commands out",
        "voxshape.services.arbiter.node",
        "add_arguments",
        "run",
    ),
    "sim-teacher": (
        "run the simulated teacher: watches a robot, speaks through the speech service",
        "voxshape.services.simteacher.node",
        "add_arguments",
        "run",
    ),
    "experiment": (
        "run the paper's experiments in-process (simulated teacher): tables and figure",
        "voxshape.lab.experiment.commands",
        "add_arguments",
        "run",
    ),
}


def _adder(command: str) -> Adder:
    _, module, add, _ = COMMANDS[command]
    return getattr(importlib.import_module(module), add)


def _runner(command: str) -> Runner:
    _, module, _, run = COMMANDS[command]
    return getattr(importlib.import_module(module), run)


def parser(only: str | None = None) -> argparse.ArgumentParser:
    """The whole command line; with `only`, the arguments of that command alone (the others
    are listed, their modules not imported)."""
    top = argparse.ArgumentParser(
        prog="voxshape",
        description="Teach a robot by voice: SARSA(lambda) with dynamic reward shaping.",
    )
    top.add_argument("--log-level", help="DEBUG, INFO, WARNING... (VOXSHAPE_LOG_LEVEL)")
    sub = top.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (text, *_) in COMMANDS.items():
        command = sub.add_parser(name, help=text, description=text)
        if only in (None, name):
            _adder(name)(command)
    return top


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    end_with_parent()  # a service of a launcher's ends with it, however the launcher ends
    named = next((a for a in argv if a in COMMANDS), None)
    args = parser(only=named or "").parse_args(argv)
    configure_logging(args.log_level)
    # `kill -USR1 <pid>` prints where every thread of a stuck process is (the demo does it
    # for each service when no episode ends); not when main() runs in a process whose stderr
    # is no file (a test's captured output).
    with contextlib.suppress(io.UnsupportedOperation):
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    try:
        return _runner(args.command)(args)
    except (
        BusError,
        ConfigError,
        TopologyError,
        VocabularyError,
        ProtocolError,
        MapError,
        SettingsError,
        RunError,
    ) as e:
        print(f"voxshape {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # `voxshape listen | head`
        sys.stderr.close()
        return 0


def program() -> NoReturn:
    """`voxshape` as a program: main(), then an exit that skips the interpreter's
    finalization. zenoh's native threads may still take the GIL while Python 3.11 finalizes,
    which aborts a process whose work is done ("FATAL: exception not rethrown", exit -6)."""
    try:
        code = main()
    except SystemExit as e:  # argparse's --help and usage errors
        code = e.code if isinstance(e.code, int) else int(e.code is not None)
    # What finalization would do, as multiprocessing's children do before their os._exit:
    # join non-daemon threads, run atexit's functions (logging, rerun, the router's files).
    threading._shutdown()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):  # a closed pipe (`voxshape listen | head`)
            stream.flush()
    os._exit(code)


if __name__ == "__main__":
    program()

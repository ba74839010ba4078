"""`voxshape`: one command, one subcommand per service or tool."""

from __future__ import annotations

import argparse
import contextlib
import faulthandler
import io
import signal
import sys
from collections.abc import Callable
from types import ModuleType

from protocol import ProtocolError, VocabularyError
from services import demo, launcher, router, tools
from services.arbiter import node as arbiter_node
from services.deploy import certs as deploy_certs
from services.experiment import commands as experiment_commands
from services.learner import commands as learner_commands
from services.learner import node as learner_node
from services.learner.config import SettingsError
from services.logger import node as logger_node
from services.logger import replay as logger_replay
from services.logger import report as logger_report
from services.logger import view as logger_view
from services.logger.run import RunError
from services.runtime import BusError, ConfigError, configure_logging
from services.sim import commands as sim_commands
from services.sim import node as sim_node
from services.sim.maps import MapError
from services.simteacher import node as simteacher_node
from services.speech import node as speech_node
from services.teacher import node as teacher_node
from services.topology import TopologyError

Runner = Callable[[argparse.Namespace], int]
Adder = Callable[[argparse.ArgumentParser], None]


def _module(module: ModuleType) -> tuple[Adder, Runner]:
    return module.add_arguments, module.run


# name -> (help, add its arguments, run it). Services whose issues have not landed are absent.
COMMANDS: dict[str, tuple[str, Adder, Runner]] = {
    "demo": ("run the main job in a local session (no docker, no manual router)", *_module(demo)),
    "up": (
        "start the local session: every service of compose.yaml as its own process",
        *_module(launcher),
    ),
    "router": ("run the zenoh router of a session", *_module(router)),
    "certs": (
        "make a development CA, TLS certificates and passwords for a secured session",
        *_module(deploy_certs),
    ),
    "sim": ("run the simulator: PyBullet world, robots, episodes", *_module(sim_node)),
    "learner": (
        "run the learner: SARSA(lambda) with dynamic reward shaping",
        *_module(learner_node),
    ),
    "train": (
        "train plain SARSA(lambda) in one process and report convergence",
        *_module(learner_commands),
    ),
    "map": (
        "draw a task's map (start, goal, optional path and scan) as PNG",
        sim_commands.add_map_arguments,
        sim_commands.map_command,
    ),
    "bench": (
        "measure and print performance figures",
        sim_commands.add_bench_arguments,
        sim_commands.bench_command,
    ),
    "status": ("list the nodes present in a session", tools.add_status_arguments, tools.status),
    "listen": (
        "print every message of a session, decoded",
        tools.add_listen_arguments,
        tools.listen,
    ),
    "dataflow": (
        "print who publishes and subscribes to what (protocol/dataflow.py)",
        tools.add_dataflow_arguments,
        tools.show_dataflow,
    ),
    "vocabulary": (
        "check a vocabulary file and list its phrases",
        tools.add_vocabulary_arguments,
        tools.vocabulary,
    ),
    "logger": (
        "record the session: event log, rerun recording, live viewer server",
        *_module(logger_node),
    ),
    "view": ("look at a live or recorded session in rerun's viewer", *_module(logger_view)),
    "replay": ("re-render a session's recording from its event log", *_module(logger_replay)),
    "report": ("pictures and a summary of a recorded session", *_module(logger_report)),
    "speech": (
        "run the speech service: teachers' audio (or said text) in, utterances out",
        *_module(speech_node),
    ),
    "teach": (
        "teach a robot: speak, stream WAV files or type words; see what was understood",
        *_module(teacher_node),
    ),
    "arbiter": (
        "run the feedback arbiter: utterances in, credited rewards and commands out",
        *_module(arbiter_node),
    ),
    "sim-teacher": (
        "run the simulated teacher: watches a robot, speaks through the speech service",
        *_module(simteacher_node),
    ),
    "experiment": (
        "run the paper's experiments in-process (simulated teacher): tables and figure",
        *_module(experiment_commands),
    ),
}


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(
        prog="voxshape",
        description="Teach a robot by voice: SARSA(lambda) with dynamic reward shaping.",
    )
    top.add_argument("--log-level", help="DEBUG, INFO, WARNING... (VOXSHAPE_LOG_LEVEL)")
    sub = top.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (text, add, _) in COMMANDS.items():
        add(sub.add_parser(name, help=text, description=text))
    return top


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    configure_logging(args.log_level)
    # `kill -USR1 <pid>` prints where every thread of a stuck process is (the demo does it
    # for each service when no episode ends); not when main() runs in a process whose stderr
    # is no file (a test's captured output).
    with contextlib.suppress(io.UnsupportedOperation):
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    try:
        return COMMANDS[args.command][2](args)
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


if __name__ == "__main__":
    sys.exit(main())

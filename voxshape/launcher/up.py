"""`voxshape up`: the local session, every service of compose.yaml as its own process.

Starts each service (session.py: each once its dependencies have announced their presence),
prefixes and interleaves their logs, and stops them all cleanly on Ctrl-C or SIGTERM. If a
service dies it stops the others and exits non-zero, naming the service.

Each `voxshape up` (and `voxshape demo`) is a new run: an earlier run in runs/<session>/ is
kept aside under a dated name and the learners start afresh, unless --resume. Its flags
--task, --rtf and --robots set the variables compose.yaml gives the services; --set goes to
the learner, which records its settings in runs/<session>/settings.json.
"""

from __future__ import annotations

import argparse
import os
import socket
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import IO

from voxshape.launcher.record import RECORD_FILE, SessionRecord, holder_of
from voxshape.launcher.session import (
    INHERITED_SETTINGS,
    LaunchAborted,
    LocalSession,
    ServiceDied,
    interrupt_on_stop_signals,
)
from voxshape.launcher.topology import (
    ServiceSpec,
    find_compose_file,
    load_topology,
    local_variables,
)
from voxshape.protocol import ProtocolError, check_id
from voxshape.runtime import BusError, ConfigError, free_loopback_port
from voxshape.runtime.config import tcp_address
from voxshape.services.learner import checkpoint
from voxshape.services.learner.config import add_settings_argument, with_settings
from voxshape.services.logger.run import RUNS, hold_run, holds_a_run, keep_earlier_run
from voxshape.services.web import page_url
from voxshape.world.maps import load_map

DEFAULT_ROUTER = "tcp/127.0.0.1:7447"  # where `voxshape teach` and the tools connect by default
WEB_PORT = 8080  # compose's port of the web page


# The flags that set compose.yaml's variables: flag -> variable.
SESSION_FLAGS = {"task": "VOXSHAPE_TASK", "rtf": "VOXSHAPE_RTF", "robots": "VOXSHAPE_ROBOTS"}


def add_arguments(
    parser: argparse.ArgumentParser, defaults: Mapping[str, str] | None = None
) -> None:
    """The launcher's flags. `defaults`: the command's own value of a session flag (by flag
    name) when neither the flag nor its variable is given; without one, compose.yaml's."""
    parser.add_argument("--compose", type=Path, help="compose file (default: ./compose.yaml)")
    parser.add_argument("--profile", action="append", default=[], help="compose profile(s)")
    parser.add_argument("--port", type=int, help="router port on 127.0.0.1 (default 7447)")
    parser.add_argument(
        "--session",
        type=session_id,
        default=os.environ.get("VOXSHAPE_SESSION") or (defaults or {}).get("session"),
        help="the session's name, and its run folder runs/NAME/ (VOXSHAPE_SESSION; default: "
        + ((defaults or {}).get("session") or "compose.yaml's, default")
        + ")",
    )
    parser.add_argument("--ready-timeout", type=float, default=30.0, help="seconds per service")

    def default(flag: str) -> str | None:  # a string default goes through `type` too
        return os.environ.get(SESSION_FLAGS[flag]) or (defaults or {}).get(flag)

    def said(flag: str) -> str:
        value = (defaults or {}).get(flag)
        return f"default {value}" if value else "default: compose.yaml's"

    parser.add_argument(
        "--task",
        default=default("task"),
        help=f"task number or map file (VOXSHAPE_TASK; {said('task')})",
    )
    parser.add_argument(
        "--rtf",
        type=positive_float,
        default=default("rtf"),
        help=f"simulated seconds per wall second, paced (VOXSHAPE_RTF; {said('rtf')})",
    )
    parser.add_argument(
        "--robots",
        type=robot_list,
        default=default("robots"),
        help="the robots, comma-separated: one simulator drives them, one learner per robot "
        f"(VOXSHAPE_ROBOTS; {said('robots')})",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="go on with the run in runs/<session>/ (its event log, the learners' "
        "checkpoints); without it, an earlier run there is kept aside and this one starts "
        "afresh",
    )
    parser.add_argument(
        "--no-restart",
        dest="restart",
        action="store_false",
        help="a service that dies stops the session (default: restarted as compose.yaml's "
        "`restart` says)",
    )
    add_settings_argument(parser)  # the learner's; it records them in runs/<session>/


def add_up_arguments(parser: argparse.ArgumentParser) -> None:
    """`voxshape up`'s flags: the launcher's, and --no-sim for a session of real robots."""
    add_arguments(parser)
    parser.add_argument(
        "--no-sim",
        action="store_true",
        help="every service but the simulator: the robots are real, each brought by "
        "`voxshape ros2` (docs/robot.md)",
    )


def without_simulator(specs: list[ServiceSpec]) -> list[ServiceSpec]:
    """The services but the simulator, and nothing waiting for it."""
    return [
        replace(s, depends_on=tuple(d for d in s.depends_on if d != "sim"))
        for s in specs
        if s.name != "sim"
    ]


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text} is not above 0")
    return value


def session_id(text: str) -> str:
    try:
        return check_id(text, "session")
    except ProtocolError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def robot_list(text: str) -> tuple[str, ...]:
    """`r1,r2` as robot ids (checked, in order, without repeats)."""
    try:
        robots = tuple(dict.fromkeys(check_id(r.strip(), "robot") for r in text.split(",")))
    except ProtocolError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return robots


def session_variables(
    args: argparse.Namespace, defaults: Mapping[str, str] | None = None
) -> dict[str, str]:
    """The variables compose.yaml is read with: the local ones, the command's `defaults`, the
    shell's, then the flags."""
    variables = local_variables({**(defaults or {}), **os.environ})
    if args.session is not None:
        variables["VOXSHAPE_SESSION"] = args.session
    if args.port is not None:
        variables["VOXSHAPE_ROUTER"] = variables["VOXSHAPE_ROUTER_LISTEN"] = (
            f"tcp/127.0.0.1:{args.port}"
        )
    if args.task is not None:
        load_map(args.task)  # a MapError now rather than a simulator dying
        variables["VOXSHAPE_TASK"] = args.task
    if args.rtf is not None:
        variables["VOXSHAPE_RTF"] = f"{args.rtf:g}"
    if args.robots is not None:
        variables["VOXSHAPE_ROBOTS"] = ",".join(args.robots)
    if "VOXSHAPE_WEB_PORT" not in variables and not _can_listen("127.0.0.1", WEB_PORT):
        # another session's page has the usual port: this one's goes elsewhere (up prints it)
        variables["VOXSHAPE_WEB_PORT"] = str(free_loopback_port())
    robots = [r for r in variables.get("VOXSHAPE_ROBOTS", "").split(",") if r]
    if robots and variables.get("VOXSHAPE_ROBOT") not in robots:
        variables["VOXSHAPE_ROBOT"] = robots[0]  # the one a simulated teacher watches
    return variables


def local_session(
    args: argparse.Namespace, defaults: Mapping[str, str] | None = None
) -> LocalSession:
    """The session of compose.yaml with the flags' variables (over the shell's, over
    `defaults`), its run directory prepared (ConfigError if its router's port is taken:
    another session runs)."""
    variables = session_variables(args, defaults)
    path = args.compose or find_compose_file()
    specs = load_topology(path, variables, tuple(args.profile))
    if getattr(args, "no_sim", False):
        specs = without_simulator(specs)
    specs = with_learner_settings(specs, args.set)
    session = LocalSession(
        specs,
        variables["VOXSHAPE_ROUTER"],
        args.ready_timeout,
        getattr(args, "restart", True),
        # settings compose.yaml does not give (the log level): the shell's, else the command's
        environment={k: variables[k] for k in INHERITED_SETTINGS if k in variables},
    )
    taken = busy_endpoints(session.variable("router", "VOXSHAPE_LISTEN") or "")
    if taken:
        raise ConfigError(port_taken(taken))
    said, session.run_lock = prepare_run(RUNS / session.session_id, args.resume, args.command)
    session.record = SessionRecord(
        RUNS / session.session_id / RECORD_FILE, session.session_id, session.router
    )
    session.say(said)
    return session


def port_taken(taken: list[str]) -> str:
    """Why a session cannot start on `taken` endpoints: whose session holds them, if a run
    record here says so, and what to do."""
    holder = next(filter(None, (holder_of(RUNS, endpoint) for endpoint in taken)), None)
    whose = (
        f"it is {holder.describe()}"
        if holder is not None
        else "is a session running already? (`voxshape status --connect ENDPOINT` names it)"
    )
    return (
        f"{', '.join(taken)} is in use: {whose}. --port chooses another, and --session NAME a "
        "name and a runs/NAME/ of this one's own"
    )


def with_learner_settings(specs: list[ServiceSpec], settings: list[str]) -> list[ServiceSpec]:
    """The learner given the `--set` settings (checked here first: SettingsError names a bad
    one before anything starts)."""
    with_settings(settings)
    added = tuple(a for setting in settings for a in ("--set", setting))
    return [replace(s, command=s.command + added) if s.name == "learner" else s for s in specs]


def busy_endpoints(endpoints: str) -> list[str]:
    """The tcp/tls endpoints of a comma list that something already listens on."""
    busy = []
    for endpoint in filter(None, endpoints.split(",")):
        address = tcp_address(endpoint)
        if address is not None and not _can_listen(address[0] or "0.0.0.0", address[1]):
            busy.append(endpoint)
    return busy


def _can_listen(host: str, port: int) -> bool:
    """Whether nothing listens on host:port. SO_REUSEADDR, as a router's listener has: the
    connections of a session just stopped, left in TIME_WAIT, do not count."""
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError:
            return False
    return True


def prepare_run(path: Path, resume: bool, holder: str) -> tuple[str, IO[str]]:
    """Makes `path` (runs/<session>/) this run's, held while it lives (RunError if a live
    session holds it): an earlier run there is kept aside, unless `resume`. What happened,
    in one line, and the lock to keep open."""
    lock = hold_run(path, holder)
    if resume:
        return _resumed(path), lock
    if not holds_a_run(path):
        return f"a new run in {path}", lock
    kept = keep_earlier_run(path)  # its lock goes with it, held until the new one is
    new_lock = hold_run(path, holder)
    lock.close()
    return (
        f"{path} held an earlier run: kept as {kept}; this run starts fresh (--resume "
        "continues it)",
        new_lock,
    )


def _resumed(path: Path) -> str:
    """What --resume goes on with in `path`."""
    if not holds_a_run(path):
        return f"--resume: {path} holds no earlier run; this run starts fresh"
    learners = sorted(p for p in path.glob("learner-*.npz") if not p.name.endswith(".prev.npz"))
    resumed = [
        f"learner {p.stem.removeprefix('learner-')} at episode {seen[0]} ({seen[1]} states)"
        for p in learners
        if (seen := checkpoint.peek(p)) is not None
    ]
    return (
        f"resuming the run in {path}: {', '.join(resumed) or 'no learner checkpoint'}; "
        "its event log goes on (the simulator counts episodes from 0 again)"
    )


def run(args: argparse.Namespace) -> int:
    interrupt_on_stop_signals()
    session = local_session(args)
    names = ", ".join(s.name for s in session.specs)
    session.say(f"starting {len(session.specs)} service(s) from compose: {names}")
    code = 0
    try:
        took = session.start()
        session.say(f"ready in {took:.1f} s: router at {session.router}; Ctrl-C stops the session")
        session.say(next_steps(session))
        if (url := web_page(session)) is not None:
            session.say(f"teach in a browser: {url}")
        session.run()
    except ServiceDied as e:
        session.say(f"error: {e}; stopping the session")
        code = 1
    except (LaunchAborted, BusError) as e:
        session.say(f"error: {e}")
        code = 1
    finally:
        codes = session.stop()
    unclean = {n: c for n, c in codes.items() if c not in (0, None)}
    if unclean and code == 0:
        session.say(f"services exited uncleanly: {unclean}")
        code = 1
    session.say("stopped" if code == 0 else f"stopped with errors (exit {code})")
    return code


def web_page(session: LocalSession) -> str | None:
    """The address of the session's web page (docs/web.md), if compose runs one."""
    port = session.variable("web", "VOXSHAPE_WEB_PORT")
    if port is None:
        return None
    address = session.variable("web", "VOXSHAPE_WEB_ADDRESS") or "127.0.0.1"
    return page_url(address, port, bool(session.variable("web", "VOXSHAPE_WEB_CERT")))


def next_steps(session: LocalSession) -> str:
    """What to run next, with this session's id, robots and router."""
    run_dir = RUNS / session.session_id
    robots = (session.variable("sim", "VOXSHAPE_ROBOTS") or "r1").split(",")
    connect = "" if session.router == DEFAULT_ROUTER else f" --connect {session.router}"
    secrets = session.variable("router", "VOXSHAPE_SECRETS")
    if secrets:  # a secured session: a teacher's user name is its teacher id
        connect += f" --secrets {secrets} --user ana --teacher ana"
    others = f" (or {', '.join(robots[1:])})" if robots[1:] else ""
    return (
        f"teach it: voxshape teach --session {session.session_id}{connect} --robot {robots[0]}"
        f"{others}; watch it: voxshape view; look at the run: voxshape report {run_dir}"
    )

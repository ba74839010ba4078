"""`voxshape up`: the local session, every service of compose.yaml as its own process.

Starts each service (dependencies first, each once its dependencies have announced their
presence), prefixes and interleaves their logs, and stops them all cleanly on Ctrl-C or
SIGTERM. If a service dies it stops the others and exits non-zero, naming the service.

Each `voxshape up` (and `voxshape demo`) is a new run: an earlier run in runs/<session>/ is
kept aside under a dated name and the learners start afresh, unless --resume. Its flags
--task, --rtf and --robots set the variables compose.yaml gives the services.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import IO

from protocol import ProtocolError, check_id
from services.learner import checkpoint
from services.logger.run import RUNS, keep_earlier_run
from services.runtime import (
    BusError,
    ConfigError,
    Node,
    Presence,
    Tick,
    bus_config,
    free_loopback_port,
)
from services.runtime.config import tcp_address
from services.teacher.web import page_url
from services.topology import ServiceSpec, find_compose_file, load_topology, local_variables
from services.world.maps import load_map

STOP_GRACE_S = 10.0
SLOW_STOP_S = 2.0  # a service slower than this to stop is named (most take 0.1-0.5 s)
INHERITED_SETTINGS = {"VOXSHAPE_LOG_LEVEL"}  # the shell's, though compose.yaml does not set it
DEFAULT_ROUTER = "tcp/127.0.0.1:7447"  # where `voxshape teach` and the tools connect by default
WEB_PORT = 8080  # compose's port of the web page


MAX_RESTARTS = 5  # a service's restarts within RESTART_WINDOW_S before the session stops
RESTART_WINDOW_S = 60.0
FIRST_BACKOFF_S, MAX_BACKOFF_S = 0.5, 8.0  # doubling with each restart in the window


def how_it_ended(code: int) -> str:
    return f"was killed by {signal.Signals(-code).name}" if code < 0 else f"exited with {code}"


class ServiceDied(RuntimeError):
    def __init__(self, name: str, code: int, restarts: int = 0) -> None:
        self.name, self.code = name, code
        given_up = f" ({restarts} restarts within {RESTART_WINDOW_S:g} s: given up)"
        super().__init__(f"service {name!r} {how_it_ended(code)}" + (given_up if restarts else ""))


class LaunchAborted(RuntimeError):
    """Stopped by a signal while starting, or a service did not announce itself in time."""


def resolve_command(command: tuple[str, ...]) -> list[str]:
    """`voxshape ...` runs this installation's voxshape; anything else is looked up on PATH."""
    head = command[0]
    beside_python = Path(sys.executable).parent / head
    found = str(beside_python) if beside_python.exists() else shutil.which(head)
    if found is None:
        raise LaunchAborted(f"command {head!r} not found on PATH")
    return [found, *command[1:]]


class LocalSession:
    """A running local session: child processes plus the launcher's own bus node."""

    def __init__(
        self, specs: list[ServiceSpec], router: str, ready_timeout: float, restart: bool = True
    ) -> None:
        """`restart`: follow each service's restart policy (else any death stops it all)."""
        self.specs = specs
        self.router = router
        self.ready_timeout = ready_timeout
        self.restart = restart
        self._restarted: dict[str, list[float]] = {}  # name -> monotonic times of restarts
        self._restart_due: dict[str, float] = {}
        self.procs: dict[str, subprocess.Popen] = {}
        self.present: set[str] = set()
        self.bus: Node | None = None
        self._print_lock = threading.Lock()
        self._width = max(len(s.name) for s in specs)
        self._stop_requested = False
        self._inputs: list[tuple[str, str]] = []  # the launcher node's, declared on joining

    @property
    def session_id(self) -> str:
        """The session the services join (compose's VOXSHAPE_SESSION, default `default`)."""
        given = (s.environment.get("VOXSHAPE_SESSION") for s in self.specs)
        return next((g for g in given if g), "default")

    def variable(self, service: str, name: str) -> str | None:
        """A variable as compose.yaml gives it to `service` (None: no such service or variable)."""
        spec = next((s for s in self.specs if s.name == service), None)
        return spec.environment.get(name) if spec else None

    # -- starting -----------------------------------------------------------------------
    def input(self, name: str, key: str) -> None:
        """An input of the launcher's own node. Declared before start() is, it is there as soon
        as the node joins the bus, before any service but the router starts, so none of their
        messages on it is missed."""
        self._inputs.append((name, key))
        if self.bus is not None:
            self.bus.input(name, key)

    def start(self) -> float:
        """Starts every service; returns seconds until all were present."""
        t0 = time.monotonic()
        for spec in self.specs:
            self._wait_until(lambda s=spec: all(self._is_up(d) for d in s.depends_on), spec.name)
            self._spawn(spec)
        self._wait_until(lambda: all(self._is_up(s.name) for s in self.specs), "all services")
        return time.monotonic() - t0

    def _is_up(self, name: str) -> bool:
        spec = next(s for s in self.specs if s.name == name)
        if not spec.on_bus:  # nothing to wait for but its process
            return spec.name in self.procs
        return spec.node in self.present

    def _spawn(self, spec: ServiceSpec) -> None:
        # As in its container, a service's VOXSHAPE_* settings are those compose.yaml gives it
        # (a VOXSHAPE_CONNECT the user exported for a remote session must not reach the router)
        inherited = {
            k: v
            for k, v in os.environ.items()
            if not k.startswith("VOXSHAPE_") or k in INHERITED_SETTINGS
        }
        env = {**inherited, **spec.environment, "PYTHONUNBUFFERED": "1"}
        proc = subprocess.Popen(
            resolve_command(spec.command),
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # Ctrl-C reaches the launcher, which stops them in order
        )
        self.procs[spec.name] = proc
        threading.Thread(target=self._relay, args=(spec.name, proc.stdout), daemon=True).start()
        self.say(f"started {spec.name} (pid {proc.pid}): {' '.join(spec.command)}")

    def _relay(self, name: str, stream: IO[bytes]) -> None:
        for raw in iter(stream.readline, b""):
            line = raw.decode(errors="replace").rstrip()
            with self._print_lock:
                print(f"{name:<{self._width}} | {line}", flush=True)

    def say(self, text: str) -> None:
        with self._print_lock:
            print(f"{'up':<{self._width}} | {text}", flush=True)

    def _connect(self, deadline: float) -> Node:
        """The launcher's own node, a client of the session router (retried until deadline)."""
        config = replace(
            bus_config("launcher"), mode="client", connect=(self.router,), connect_timeout=1.0
        )
        while True:
            self.check_children()
            try:
                node = Node("launcher", config, quiet=True)
            except BusError:
                if time.monotonic() > deadline or self._stop_requested:
                    raise
                continue
            node.watch_presence()
            for name, key in self._inputs:
                node.input(name, key)
            return node

    def _wait_until(self, condition: object, what: str) -> None:
        deadline = time.monotonic() + self.ready_timeout
        if condition():
            return
        if self.bus is None:
            self.bus = self._connect(deadline)
        for event in self.bus.events(tick=0.1):
            self._observe(event)
            if condition():
                return
            if time.monotonic() > deadline:
                missing = [
                    s.name for s in self.specs if s.name in self.procs and not self._is_up(s.name)
                ]
                raise LaunchAborted(
                    f"waited {self.ready_timeout:g} s for {what}; not present: {', '.join(missing)}"
                )
        raise LaunchAborted("stopped while starting")

    # -- running ------------------------------------------------------------------------
    def _observe(self, event: object) -> None:
        if isinstance(event, Presence):
            (self.present.add if event.alive else self.present.discard)(event.node)
            spec = next((s for s in self.specs if s.node == event.node), None)
            if spec is not None and not event.alive and self.procs[spec.name].poll() is None:
                self.say(f"warning: {spec.name} left the bus but its process is alive")
        elif isinstance(event, Tick):
            self.check_children()

    def check_children(self) -> None:
        """Restarts the services whose policy says so, when their backoff is over; raises
        ServiceDied for one that must not (or can no longer) be restarted."""
        now = time.monotonic()
        for spec in self.specs:
            proc = self.procs.get(spec.name)
            code = None if proc is None else proc.poll()
            if code is None:
                continue
            due = self._restart_due.get(spec.name)
            if due is None:
                self._restart_due[spec.name] = now + self._backoff(spec, code, now)
            elif now >= due:
                del self._restart_due[spec.name]
                self._restarted.setdefault(spec.name, []).append(now)
                self._spawn(spec)

    def _backoff(self, spec: ServiceSpec, code: int, now: float) -> float:
        """Seconds to wait before restarting a service that ended with `code`."""
        wanted = spec.restart in ("always", "unless-stopped") or (
            spec.restart == "on-failure" and code != 0
        )
        if not (self.restart and wanted):
            raise ServiceDied(spec.name, code)
        recent = [t for t in self._restarted.get(spec.name, []) if now - t < RESTART_WINDOW_S]
        self._restarted[spec.name] = recent
        if len(recent) >= MAX_RESTARTS:
            raise ServiceDied(spec.name, code, len(recent))
        delay = min(MAX_BACKOFF_S, FIRST_BACKOFF_S * 2 ** len(recent))
        self.say(
            f"{spec.name} {how_it_ended(code)}: restarting it in {delay:g} s (restart "
            f"{len(recent) + 1} of at most {MAX_RESTARTS} a minute; --no-restart stops instead)"
        )
        return delay

    def run(self) -> None:
        """Watches the session until a signal (returns) or a service dies (raises)."""
        assert self.bus is not None
        for event in self.bus.events(tick=0.2):
            self._observe(event)

    def cpu_seconds(self) -> dict[str, float]:
        """CPU seconds each running service has used so far (Linux; empty elsewhere): a
        service whose figure stops growing is blocked, not slow."""
        used = {}
        for name, proc in self.procs.items():
            try:
                fields = Path(f"/proc/{proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
            except (OSError, IndexError):
                continue
            used[name] = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        return used

    def print_stacks(self, wait: float = 1.0) -> None:
        """Has every running voxshape service print where each of its threads is (SIGUSR1,
        see services/cli.py), relayed with the rest of its output within `wait` seconds.
        Other commands (the viewer) are left alone: SIGUSR1 would end most of them."""
        for spec in self.specs:
            proc = self.procs.get(spec.name)
            if spec.command[0] == "voxshape" and proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGUSR1)
        time.sleep(wait)

    # -- stopping -----------------------------------------------------------------------
    def stop(self) -> dict[str, int | None]:
        """SIGTERM in reverse start order, SIGKILL after the grace period; exit codes. The
        launcher leaves the bus first, while its router still runs (closing a session whose
        router is gone can wait on zenoh)."""
        if self.bus is not None:
            self.bus.close()
            self.bus = None
        for name in reversed(list(self.procs)):
            proc = self.procs[name]
            if proc.poll() is None:
                asked = time.monotonic()
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(STOP_GRACE_S)
                except subprocess.TimeoutExpired:
                    self.say(f"{name} ignored SIGTERM for {STOP_GRACE_S:g} s: killing it")
                    proc.kill()
                    proc.wait()
                if (took := time.monotonic() - asked) > SLOW_STOP_S:
                    self.say(f"{name} took {took:.1f} s to stop")
        # one awaiting its restart died during the session, not at its end
        return {
            name: None if name in self._restart_due else proc.returncode
            for name, proc in self.procs.items()
        }


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


def robot_list(text: str) -> tuple[str, ...]:
    """`r1,r2` as robot ids (checked, in order, without repeats)."""
    try:
        robots = tuple(dict.fromkeys(check_id(r.strip(), "robot") for r in text.split(",")))
    except ProtocolError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return robots


def session_variables(args: argparse.Namespace) -> dict[str, str]:
    """The variables compose.yaml is read with: the local ones, the shell's, then the flags."""
    variables = local_variables()
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


def open_session(args: argparse.Namespace) -> LocalSession:
    """The session of compose.yaml with the flags' variables, its run directory prepared
    (ConfigError if its router's port is taken: another session runs)."""
    variables = session_variables(args)
    path = args.compose or find_compose_file()
    specs = load_topology(path, variables, tuple(args.profile))
    if getattr(args, "no_sim", False):
        specs = without_simulator(specs)
    session = LocalSession(
        specs, variables["VOXSHAPE_ROUTER"], args.ready_timeout, getattr(args, "restart", True)
    )
    taken = busy_endpoints(session.variable("router", "VOXSHAPE_LISTEN") or "")
    if taken:
        raise ConfigError(
            f"{', '.join(taken)} is in use: is a session running already? (`voxshape status` "
            "says who is there; --port chooses another)"
        )
    session.say(prepare_run(RUNS / session.session_id, args.resume))
    return session


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


def prepare_run(path: Path, resume: bool) -> str:
    """Makes `path` (runs/<session>/) this run's: an earlier run there is kept aside, unless
    `resume`. Says what happened, in one line."""
    if resume:
        if not path.exists() or not any(path.iterdir()):
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
    kept = keep_earlier_run(path)
    if kept is None:
        return f"a new run in {path}"
    return (
        f"{path} held an earlier run: kept as {kept}; this run starts fresh (--resume continues it)"
    )


def run(args: argparse.Namespace) -> int:
    session = open_session(args)
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

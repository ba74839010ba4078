"""`voxshape up`: the local session, every service of compose.yaml as its own process.

Starts each service (dependencies first, each once its dependencies have announced their
presence), prefixes and interleaves their logs, and stops them all cleanly on Ctrl-C or
SIGTERM. If a service dies it stops the others and exits non-zero, naming the service.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import IO

from services.runtime import BusError, Node, Presence, Tick, bus_config
from services.topology import ServiceSpec, find_compose_file, load_topology, local_variables

STOP_GRACE_S = 10.0


class ServiceDied(RuntimeError):
    def __init__(self, name: str, code: int) -> None:
        self.name, self.code = name, code
        how = f"was killed by {signal.Signals(-code).name}" if code < 0 else f"exited with {code}"
        super().__init__(f"service {name!r} {how}")


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

    def __init__(self, specs: list[ServiceSpec], router: str, ready_timeout: float) -> None:
        self.specs = specs
        self.router = router
        self.ready_timeout = ready_timeout
        self.procs: dict[str, subprocess.Popen] = {}
        self.present: set[str] = set()
        self.bus: Node | None = None
        self._print_lock = threading.Lock()
        self._width = max(len(s.name) for s in specs)
        self._stop_requested = False
        self._inputs: list[tuple[str, str]] = []  # the launcher node's, declared on joining

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
        env = {**os.environ, **spec.environment, "PYTHONUNBUFFERED": "1"}
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
            self._check_children()
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
            self._check_children()

    def _check_children(self) -> None:
        for name, proc in self.procs.items():
            code = proc.poll()
            if code is not None:
                raise ServiceDied(name, code)

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
        """SIGTERM in reverse start order, SIGKILL after the grace period; exit codes."""
        for name in reversed(list(self.procs)):
            proc = self.procs[name]
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(STOP_GRACE_S)
                except subprocess.TimeoutExpired:
                    self.say(f"{name} ignored SIGTERM for {STOP_GRACE_S:g} s: killing it")
                    proc.kill()
                    proc.wait()
        if self.bus is not None:
            self.bus.close()
        return {name: proc.returncode for name, proc in self.procs.items()}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--compose", type=Path, help="compose file (default: ./compose.yaml)")
    parser.add_argument("--profile", action="append", default=[], help="compose profile(s)")
    parser.add_argument("--port", type=int, help="router port on 127.0.0.1 (default 7447)")
    parser.add_argument("--ready-timeout", type=float, default=30.0, help="seconds per service")


def open_session(args: argparse.Namespace) -> LocalSession:
    variables = local_variables()
    if args.port is not None:
        variables["VOXSHAPE_ROUTER"] = variables["VOXSHAPE_ROUTER_LISTEN"] = (
            f"tcp/127.0.0.1:{args.port}"
        )
    path = args.compose or find_compose_file()
    specs = load_topology(path, variables, tuple(args.profile))
    return LocalSession(specs, variables["VOXSHAPE_ROUTER"], args.ready_timeout)


def run(args: argparse.Namespace) -> int:
    session = open_session(args)
    names = ", ".join(s.name for s in session.specs)
    session.say(f"starting {len(session.specs)} service(s) from compose: {names}")
    code = 0
    try:
        took = session.start()
        session.say(f"ready in {took:.1f} s: router at {session.router}; Ctrl-C stops the session")
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

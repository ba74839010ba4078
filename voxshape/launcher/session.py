"""A local session's processes: each service started once its dependencies are present on the
bus, watched and restarted as its policy says, and stopped in reverse order, by pid.

`LocalSession` is the one way a session is started: `voxshape up` and the demo run compose.yaml
through it, and the benchmarks, experiments and test harnesses through `LoopbackSession`
(loopback.py), which is one too. Nothing else spawns a router.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import IO

from voxshape.launcher.record import SessionRecord
from voxshape.launcher.topology import ServiceSpec, TopologyError
from voxshape.runtime import BusError, Node, Presence, Tick, bus_config
from voxshape.runtime.node import STOP_SIGNALS
from voxshape.runtime.processes import end_process, ending_with_me

STOP_GRACE_S = 10.0
HURRY_GRACE_S = 3.0  # after a second Ctrl-C: every service asked at once, killed after this
BUS_CLOSE_S = 2.0  # the launcher's own leaving of the bus may take this long, then it goes on
SLOW_STOP_S = 2.0  # a service slower than this to stop is named (most take 0.1-0.5 s)
INHERITED_SETTINGS = {"VOXSHAPE_LOG_LEVEL"}  # the shell's, though compose.yaml does not set it
TAIL_CHARS = 2000  # of a dead service's log, in the error that names it

MAX_RESTARTS = 5  # a service's restarts within RESTART_WINDOW_S before the session stops
RESTART_WINDOW_S = 60.0
FIRST_BACKOFF_S, MAX_BACKOFF_S = 0.5, 8.0  # doubling with each restart in the window


def how_it_ended(code: int) -> str:
    return f"was killed by {signal.Signals(-code).name}" if code < 0 else f"exited with {code}"


class ServiceDied(RuntimeError):
    def __init__(self, name: str, code: int, restarts: int = 0, tail: str = "") -> None:
        self.name, self.code = name, code
        given_up = f" ({restarts} restarts within {RESTART_WINDOW_S:g} s: given up)"
        said = f"service {name!r} {how_it_ended(code)}" + (given_up if restarts else "")
        super().__init__(said + (f"; the end of its log:\n{tail}" if tail else ""))


class LaunchAborted(RuntimeError):
    """Stopped by a signal while starting, or a service did not announce itself in time."""


def interrupt_on_stop_signals() -> None:
    """SIGTERM and SIGHUP (a terminal closed) stop a launcher as Ctrl-C does, wherever it is:
    inside a node's loop as its flag, elsewhere as KeyboardInterrupt (for a command's main
    thread, never a test's process)."""
    for s in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(s, signal.default_int_handler)


def resolve_command(command: Iterable[str]) -> list[str]:
    """`voxshape ...` runs this installation's voxshape; anything else is looked up on PATH."""
    head, *rest = command
    beside_python = Path(sys.executable).parent / head
    found = str(beside_python) if beside_python.exists() else shutil.which(head)
    if found is None:
        raise LaunchAborted(f"command {head!r} not found on PATH")
    return [found, *rest]


def router_command(*flags: str) -> list[str]:
    """This installation's `voxshape router` with `flags`: for a test of the router itself
    (secured, meshed, killed); a session's router comes from compose.yaml."""
    return resolve_command(("voxshape", "router", *flags))


class LocalSession:
    """A running local session: child processes plus the launcher's own bus node."""

    def __init__(
        self,
        specs: list[ServiceSpec],
        router: str,
        ready_timeout: float,
        restart: bool = True,
        *,
        logs: Path | None = None,
        cwd: Path | None = None,
        environment: Mapping[str, str] | None = None,
    ) -> None:
        """`restart`: follow each service's restart policy (else any death stops it all).
        `logs`: a folder for each process's output (<name>.log) and the launcher's lines
        (launcher.log), else both go to stdout, prefixed. `cwd`: where the processes run.
        `environment`: variables every process gets beneath its own."""
        self.specs = list(specs)
        self.router = router
        self.ready_timeout = ready_timeout
        self.restart = restart
        self.logs, self.cwd = logs, cwd
        self.environment = dict(environment or {})
        self._restarted: dict[str, list[float]] = {}  # name -> monotonic times of restarts
        self._restart_due: dict[str, float] = {}
        self.procs: dict[str, subprocess.Popen] = {}
        self.present: set[str] = set()
        self.bus: Node | None = None
        self._print_lock = threading.Lock()
        self._width = max((len(s.name) for s in specs), default=2)
        self._stop_requested = False
        self._inputs: list[tuple[str, str]] = []  # the launcher node's (topic, of), on joining
        self.run_lock: IO[str] | None = None  # runs/<session>/ held while it runs (up.py)
        # runs/<session>/launcher.json: the launcher's and each service's pid while it runs
        self.record: SessionRecord | None = None
        self._hurry = 0  # signals received while stopping

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
    def subscribe(self, topic: str, of: str) -> None:
        """An input of the launcher's own node (Node.subscribe). Declared before start() is, it
        is there as soon as the node joins the bus, before any service but the router starts,
        so none of their messages on it is missed."""
        self._inputs.append((topic, of))
        if self.bus is not None:
            self.bus.subscribe(topic, of)

    def start(self) -> float:
        """Starts every service; returns seconds until all were present."""
        return self._launch(self.specs)

    def add(self, *specs: ServiceSpec) -> float:
        """Starts more services now, each once its dependencies are present; returns seconds
        until all were present. Their dependencies must be services of the session."""
        known = {s.name for s in self.specs} | {s.name for s in specs}
        for spec in specs:
            if unknown := [d for d in spec.depends_on if d not in known]:
                raise TopologyError(f"{spec.name!r} depends on {unknown}, not in the session")
        self.specs.extend(specs)
        self._width = max([self._width, *(len(s.name) for s in specs)])
        return self._launch(list(specs))

    def _launch(self, specs: list[ServiceSpec]) -> float:
        t0 = time.monotonic()
        for spec in specs:
            self._wait_until(lambda s=spec: all(self._is_up(d) for d in s.depends_on), spec.name)
            self._spawn(spec)
        self._wait_until(lambda: all(self._is_up(s.name) for s in specs), "all services")
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
        env = {**inherited, **self.environment, **spec.environment, "PYTHONUNBUFFERED": "1"}
        ending_with_me(env)  # it ends with this launcher, however this one ends
        log = None if self.logs is None else open(self.logs / f"{spec.name}.log", "a")  # noqa: SIM115
        try:
            proc = subprocess.Popen(
                resolve_command(spec.command),
                env=env,
                cwd=self.cwd,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE if log is None else log,
                stderr=subprocess.STDOUT,
                start_new_session=True,  # Ctrl-C reaches the launcher, which stops them in order
            )
        finally:
            if log is not None:
                log.close()  # the child holds its own
        self.procs[spec.name] = proc
        if self.record is not None:
            self.record.write({name: p.pid for name, p in self.procs.items()})
        if log is None:
            threading.Thread(target=self._relay, args=(spec.name, proc.stdout), daemon=True).start()
        self.say(f"started {spec.name} (pid {proc.pid}): {' '.join(spec.command)}")

    def _relay(self, name: str, stream: IO[bytes]) -> None:
        """Prints a service's lines; drains them unprinted once the terminal is gone (a
        service must never block on its output)."""
        for raw in iter(stream.readline, b""):
            line = raw.decode(errors="replace").rstrip()
            with self._print_lock, contextlib.suppress(OSError):
                print(f"{name:<{self._width}} | {line}", flush=True)

    def say(self, text: str) -> None:
        """A line of the launcher's: printed (nowhere, when the terminal is gone) or logged."""
        with self._print_lock, contextlib.suppress(OSError):
            if self.logs is None:
                print(f"{'up':<{self._width}} | {text}", flush=True)
            else:
                with open(self.logs / "launcher.log", "a") as log:
                    log.write(text + "\n")

    def tail(self, name: str) -> str:
        """The end of a service's log (with `logs` only; else its output went to stdout)."""
        if self.logs is None:
            return ""
        try:
            return (self.logs / f"{name}.log").read_text(errors="replace")[-TAIL_CHARS:]
        except OSError:
            return ""

    def _connect(self, deadline: float) -> Node:
        """The launcher's own node, a client of the session router (retried until deadline)."""
        config = replace(
            bus_config("launcher"),
            session=self.session_id,
            mode="client",
            connect=(self.router,),
            connect_timeout=1.0,
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
            for topic, of in self._inputs:
                node.subscribe(topic, of)
            return node

    def _wait_until(self, condition: Callable[[], bool], what: str) -> None:
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
            proc = None if spec is None else self.procs.get(spec.name)
            if proc is not None and not event.alive and proc.poll() is None:
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
            raise ServiceDied(spec.name, code, tail=self.tail(spec.name))
        recent = [t for t in self._restarted.get(spec.name, []) if now - t < RESTART_WINDOW_S]
        self._restarted[spec.name] = recent
        if len(recent) >= MAX_RESTARTS:
            raise ServiceDied(spec.name, code, len(recent), self.tail(spec.name))
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
        see voxshape/cli.py), relayed with the rest of its output within `wait` seconds.
        Other commands (the viewer) are left alone: SIGUSR1 would end most of them."""
        for spec in self.specs:
            proc = self.procs.get(spec.name)
            if spec.command[0] == "voxshape" and proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGUSR1)
        time.sleep(wait)

    # -- stopping -----------------------------------------------------------------------
    def end(self, name: str, grace: float = STOP_GRACE_S) -> int | None:
        """Ends one service by pid, for good (it is no longer the session's): SIGTERM, SIGKILL
        after `grace` seconds; its exit code, None if it had to be killed."""
        proc = self.procs.pop(name)
        self.specs = [s for s in self.specs if s.name != name]
        self._restart_due.pop(name, None)
        return end_process(proc, grace)

    def _leave_bus(self, bus: Node) -> None:
        """Closes the launcher's bus node, waiting at most BUS_CLOSE_S: a close that hangs in
        zenoh must not keep Ctrl-C from stopping the services (seen once, 27 s)."""
        closing = threading.Thread(target=bus.close, name="leave-bus", daemon=True)
        closing.start()
        closing.join(BUS_CLOSE_S)
        if closing.is_alive():
            self.say(f"the launcher's bus node did not close in {BUS_CLOSE_S:g} s: stopping anyway")

    def stop(self) -> dict[str, int | None]:
        """SIGTERM in reverse start order, SIGKILL after the grace period; exit codes. The
        launcher leaves the bus first, while its router still runs (closing a session whose
        router is gone can wait on zenoh). A signal meanwhile (a second Ctrl-C) hurries it:
        every service left is asked at once and killed HURRY_GRACE_S later, a third kills."""
        restore = self._hurry_on_signals()
        try:
            if self.bus is not None:
                self._leave_bus(self.bus)
                self.bus = None
            for name in reversed(list(self.procs)):
                if self._hurry:
                    break
                self._stop_one(name, self.procs[name])
            if self._hurry:
                self._stop_all_at_once()
        finally:
            restore()
        if self.run_lock is not None:  # the run folder is free for the next session
            self.run_lock.close()
            self.run_lock = None
        if self.record is not None:
            self.record.remove()
        # one awaiting its restart died during the session, not at its end
        return {
            name: None if name in self._restart_due else proc.returncode
            for name, proc in self.procs.items()
        }

    def _stop_one(self, name: str, proc: subprocess.Popen) -> None:
        """SIGTERM, SIGKILL after STOP_GRACE_S (or when hurried meanwhile)."""
        if proc.poll() is not None:
            return
        asked = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        while proc.poll() is None and not self._hurry:
            if time.monotonic() - asked > STOP_GRACE_S:
                self.say(f"{name} ignored SIGTERM for {STOP_GRACE_S:g} s: killing it")
                proc.kill()
                proc.wait()
            time.sleep(0.02)
        if (took := time.monotonic() - asked) > SLOW_STOP_S:
            self.say(f"{name} took {took:.1f} s to stop")

    def _stop_all_at_once(self) -> None:
        """Every service still running asked at once, killed after HURRY_GRACE_S (or a third
        signal)."""
        left = {n: p for n, p in self.procs.items() if p.poll() is None}
        self.say(f"stopping {', '.join(left) or 'nothing'} at once (again: killed at once)")
        for proc in left.values():
            proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + HURRY_GRACE_S
        while any(p.poll() is None for p in left.values()):
            if time.monotonic() > deadline or self._hurry > 1:
                for name, proc in left.items():
                    if proc.poll() is None:
                        self.say(f"killing {name} (pid {proc.pid})")
                        proc.kill()
                        proc.wait()
            time.sleep(0.02)

    def _hurry_on_signals(self) -> Callable[[], object]:
        """While stopping, a stop signal hurries the stop instead of ending the launcher
        with its services left (main thread only: signals are handled there)."""
        if threading.current_thread() is not threading.main_thread():
            return lambda: None
        previous = {s: signal.getsignal(s) for s in STOP_SIGNALS}

        def hurry(_signum: int, _frame: object) -> None:
            self._hurry += 1

        for s in STOP_SIGNALS:
            signal.signal(s, hurry)
        return lambda: [signal.signal(s, h) for s, h in previous.items()]

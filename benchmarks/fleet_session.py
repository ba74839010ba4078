"""benchmarks/fleet.py's session: the processes of one point, started in turn and ended by pid.

A router, the harness's bus node (fleet_probe.Probe), the simulator(s), the learner, the
arbiter, the speech service with the mock engine and the page's gateway, then the teachers
(fleet_clients); each process logs to <name>.log in the point's working directory.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import subprocess
import time
import urllib.request
from pathlib import Path
from typing import Any

from benchmarks.fleet_clients import browser_processes, sim_teacher_argv
from benchmarks.fleet_probe import Probe
from benchmarks.harness import VOXSHAPE, last_counters
from services.runtime import free_loopback_port
from services.runtime.processes import end_process

SERVICES = ("sim", "learner", "arbiter", "speech", "web")  # started after the router
MAX_ROBOTS_PER_SIM = 28  # services/sim/world.py MAX_ROBOTS: one collision-group bit a robot
READY_TIMEOUT_S = 180.0
# The counters of a service's log that say what it missed or dropped
MISSED = ("missed.", "rejected.", "stopped_without", "ignored.")


class Fleet:
    """The processes of one point, each ended by pid."""

    def __init__(
        self,
        workdir: Path,
        robots: tuple[str, ...],
        sim_teachers: int,
        browsers: int,
        args: argparse.Namespace,
    ) -> None:
        self.workdir, self.robots, self.args = workdir, robots, args
        self.session_id = f"fleet-{os.getpid()}-{len(robots)}x{sim_teachers + browsers}"
        self.port, self.web_port = free_loopback_port(), free_loopback_port()
        self.router = f"tcp/127.0.0.1:{self.port}"
        self.sim_teachers = [(f"t{i + 1}", robots[i % len(robots)]) for i in range(sim_teachers)]
        self.browsers = [
            (f"b{i + 1}", robots[(sim_teachers + i) % len(robots)]) for i in range(browsers)
        ]
        self.procs: dict[str, subprocess.Popen] = {}
        self.order: list[str] = []
        self.probe = Probe(self.session_id, self.router)
        # One simulator for the N robots; more only where one world cannot hold them all
        per_sim = max(1, args.robots_per_sim or MAX_ROBOTS_PER_SIM)
        chunks = [robots[i : i + per_sim] for i in range(0, len(robots), per_sim)]
        self.sims = {f"sim-{i + 1}": c for i, c in enumerate(chunks)}
        if len(chunks) == 1:
            self.sims = {"sim": chunks[0]}
        self.services = [*self.sims, *SERVICES[1:]]

    def env(self) -> dict[str, str]:
        inherited = {k: v for k, v in os.environ.items() if not k.startswith("VOXSHAPE_")}
        return {
            **inherited,
            "PYTHONUNBUFFERED": "1",
            "VOXSHAPE_SESSION": self.session_id,
            "VOXSHAPE_MODE": "client",
            "VOXSHAPE_CONNECT": self.router,
            "VOXSHAPE_LOG_FORMAT": "json",
            "VOXSHAPE_SPEECH_ENGINE": "mock",
            "VOXSHAPE_TASK": str(self.args.task),
        }

    def spawn(self, name: str, argv: list[str], env: dict[str, str] | None = None) -> None:
        log = open(self.workdir / f"{name}.log", "w")  # noqa: SIM115 (the child holds it)
        try:
            self.procs[name] = subprocess.Popen(
                argv,
                cwd=self.workdir,
                env=env or self.env(),
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,  # Ctrl-C reaches the harness, which ends them in turn
            )
        finally:
            log.close()
        self.order.append(name)

    # -- starting ---------------------------------------------------------------------------
    def start(self) -> float:
        """Starts everything and waits until it is present; seconds it took."""
        t0 = time.monotonic()
        self.workdir.mkdir(parents=True, exist_ok=True)
        self._start_router()
        self._start_services()
        self._start_teachers()
        return time.monotonic() - t0

    def _start_router(self) -> None:
        """The router, then the harness's bus node on it."""
        env = {**self.env(), "VOXSHAPE_MODE": "router", "VOXSHAPE_LISTEN": self.router}
        del env["VOXSHAPE_CONNECT"]
        self.spawn("router", [VOXSHAPE, "router", "--node", "router"], env)
        self._wait(lambda: _listening(self.port), "the router's port")
        self.probe.start()
        self._wait(self.probe.ready.is_set, "the harness's bus node")

    def _commands(self) -> dict[str, list[str]]:
        """Each service's `voxshape` arguments (without its --node)."""
        seed = str(self.args.seed)
        robots = [a for r in self.robots for a in ("--robot", r)]
        commands = {
            name: ["sim", *(a for r in mine for a in ("--robot", r)), "--seed", seed]
            for name, mine in self.sims.items()
        }
        commands |= {
            "learner": ["learner", *robots, "--fresh", "--seed", seed],
            "arbiter": ["arbiter"],
            "speech": ["speech", "--engine", "mock", "--latency", str(self.args.mock_latency)],
            "web": ["web", "--address", "127.0.0.1", "--port", str(self.web_port)],
        }
        commands["web"] += ["--max-clients", str(len(self.browsers) + 4)]
        return commands

    def _start_services(self) -> None:
        """The services, until each is present, the page serves and every robot steps."""
        commands = self._commands()
        for name in self.services:
            self.spawn(name, [VOXSHAPE, *commands[name], "--node", name])
        self._wait(lambda: self.probe.nodes() >= set(self.services), "the services")
        self._wait(lambda: _serving(self.web_port), "the page")
        self._wait(lambda: self.probe.robots_seen() >= set(self.robots), "every robot's steps")

    def _start_teachers(self) -> None:
        """The simulated people and the browsers, until all are present."""
        for i, (teacher, robot) in enumerate(self.sim_teachers):
            argv = sim_teacher_argv(teacher, robot, self.args.seed + i)
            self.spawn(f"sim-teacher-{teacher}", argv)
        args = self.args
        groups = browser_processes(
            self.browsers, self.web_port, self.workdir, args.word_every, args.seed
        )
        for name, argv in groups:
            self.spawn(name, argv)
        wanted = {t for t, _ in self.sim_teachers}
        self._wait(lambda: self.probe.nodes() >= wanted, "the simulated teachers")
        self._wait(lambda: self.probe.web_teachers() >= len(self.browsers), "the browsers' logins")

    def _wait(self, condition: Any, what: str) -> None:
        deadline = time.monotonic() + READY_TIMEOUT_S
        while not condition():
            for name, proc in self.procs.items():
                if proc.poll() is not None:
                    tail = (self.workdir / f"{name}.log").read_text()[-2000:]
                    raise RuntimeError(f"{name} ended ({proc.returncode}) before {what}:\n{tail}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"waited {READY_TIMEOUT_S:g} s for {what}")
            time.sleep(0.1)

    # -- running and after ------------------------------------------------------------------
    def pids(self) -> dict[str, int]:
        return {name: p.pid for name, p in self.procs.items() if p.poll() is None}

    def browser_records(self) -> list[dict]:
        """What each browser process saw (written when it ended)."""
        records = []
        for name in self.order:
            path = self.workdir / f"{name}.json"
            if name.startswith("browsers") and path.exists():
                records.append(json.loads(path.read_text()))
        return records

    def service_counters(self) -> dict[str, dict[str, int]]:
        """Each service's last counters of what it missed or dropped (its JSON log lines)."""
        return {name: _missed(self.workdir / f"{name}.log") for name in self.services}

    def stop(self) -> None:
        """Browsers and teachers first (they write what they saw), then the services in
        reverse, the harness's node, the router last; SIGTERM, SIGKILL after a grace."""
        for name in sorted(self.order, key=_stop_rank):
            if name == "router":
                self.probe.stop()
            proc = self.procs[name]
            if proc.poll() is None:
                end_process(proc, 15.0 if name.startswith("browsers") else 10.0)
        self.probe.stop()

    def kill_all(self) -> None:
        """Whatever is left, by pid (a harness that failed halfway)."""
        for proc in self.procs.values():
            if proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(proc.pid, signal.SIGKILL)
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(10)


def _missed(log: Path) -> dict[str, int]:
    try:
        lines = log.read_text().splitlines()
    except OSError:
        return {}
    return {k: v for k, v in last_counters(lines).items() if k.startswith(MISSED)}


def _stop_rank(name: str) -> tuple[int, str]:
    if name.startswith(("browsers", "sim-teacher")):
        return (0, name)
    if name == "router":
        return (9, name)
    service = "sim" if name.startswith("sim-") and not name.startswith("sim-teacher") else name
    return (8 - SERVICES.index(service) if service in SERVICES else 5, name)


def _listening(port: int) -> bool:
    import socket

    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex(("127.0.0.1", port)) == 0


def _serving(port: int) -> bool:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=2) as r:
            return r.status == 200
    except OSError:
        return False

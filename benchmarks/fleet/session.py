"""The fleet's session: the processes of one point, on a LoopbackSession of their own.

compose.yaml's router and its services but the logger (whose cost benchmarks/logger.py
measures): the simulator (one for each MAX_ROBOTS robots, all a world holds), the learner,
the arbiter, the speech service with the mock engine and the page's gateway; the harness's
bus node (benchmarks/probe.py); then the teachers (clients.py). Each process logs to
<name>.log in the point's working directory and is ended by pid.
"""

from __future__ import annotations

import argparse
import json
import os
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path

from benchmarks.common import checkout_environment, last_counters
from benchmarks.fleet.clients import browser_processes, sim_teacher_command
from benchmarks.probe import Probe
from voxshape.launcher import LoopbackSession
from voxshape.launcher.topology import ServiceSpec
from voxshape.runtime import free_loopback_port
from voxshape.services.sim.world import MAX_ROBOTS

LEFT_OUT = ("router", "logger")  # of compose.yaml's services: the session's own, the recorder
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
        self.web_port = free_loopback_port()
        self.sim_teachers = [(f"t{i + 1}", robots[i % len(robots)]) for i in range(sim_teachers)]
        self.browsers = [
            (f"b{i + 1}", robots[(sim_teachers + i) % len(robots)]) for i in range(browsers)
        ]
        variables = {
            "VOXSHAPE_LOG_FORMAT": "json",
            "VOXSHAPE_SPEECH_ENGINE": "mock",
            "VOXSHAPE_TASK": str(args.task),
            "VOXSHAPE_ROBOTS": ",".join(robots),
            "VOXSHAPE_WEB_PORT": str(self.web_port),
        }
        self.session = LoopbackSession(
            f"fleet-{os.getpid()}-{len(robots)}x{sim_teachers + browsers}",
            variables=variables,
            logs=workdir,
            cwd=workdir,
            ready_timeout=READY_TIMEOUT_S,
        )
        self.probe = Probe(self.session.client_config("fleet-probe", connect_timeout=20.0))
        # One simulator for the N robots; more only where one world cannot hold them all
        per_sim = max(1, args.robots_per_sim or MAX_ROBOTS)
        chunks = [robots[i : i + per_sim] for i in range(0, len(robots), per_sim)]
        self.sims = {f"sim-{i + 1}": c for i, c in enumerate(chunks)}
        if len(chunks) == 1:
            self.sims = {"sim": chunks[0]}
        others = [n for n in self.session.topology if n not in (*LEFT_OUT, "sim")]
        self.services = [*self.sims, *others]
        self.clients: list[str] = []  # the teachers' processes

    # -- starting ---------------------------------------------------------------------------
    def start(self) -> float:
        """Starts everything and waits until it is present; seconds it took."""
        t0 = time.monotonic()
        self.session.start()  # the router
        self.probe.start()
        self._until(self.probe.ready.is_set, "the harness's bus node")
        self.session.add(*self._services())
        self._until(lambda: _serving(self.web_port), "the page")
        self._until(lambda: self.probe.robots_seen() >= set(self.robots), "every robot's steps")
        self._start_teachers()
        return time.monotonic() - t0

    def _services(self) -> list[ServiceSpec]:
        """compose.yaml's services with the point's arguments, the simulators first."""
        s, seed = self.session, str(self.args.seed)
        specs = [
            s.service("sim", *(a for r in mine for a in ("--robot", r)), "--seed", seed, named=name)
            for name, mine in self.sims.items()
        ]
        arguments = {
            "learner": ["--fresh", "--seed", seed],
            "speech": ["--latency", str(self.args.mock_latency)],
            "web": ["--max-clients", str(len(self.browsers) + 4)],
        }
        return specs + [s.service(n, *arguments.get(n, [])) for n in self.services[len(specs) :]]

    def _start_teachers(self) -> None:
        """The simulated people and the browsers, until all are present (the browsers:
        logged in)."""
        s, args = self.session, self.args
        teachers = [
            s.client(
                f"sim-teacher-{teacher}",
                sim_teacher_command(teacher, robot, args.seed + i),
                environment={"VOXSHAPE_NODE": teacher},
            )
            for i, (teacher, robot) in enumerate(self.sim_teachers)
        ]
        groups = browser_processes(
            self.browsers, self.web_port, self.workdir, args.word_every, args.seed
        )
        browsers = [
            s.client(name, argv, on_bus=False, environment=checkout_environment())
            for name, argv in groups
        ]
        self.clients = [c.name for c in (*teachers, *browsers)]
        s.add(*teachers, *browsers)
        self._until(lambda: self._logins() >= len(self.browsers), "the browsers' logins")

    def _logins(self) -> int:
        """The browsers' teachers logged in: the gateway's teacher nodes present."""
        return sum(1 for node in self.probe.nodes() if node.startswith("web-"))

    def _until(self, condition: Callable[[], bool], what: str) -> None:
        deadline = time.monotonic() + READY_TIMEOUT_S
        while not condition():
            self.session.check_children()  # ServiceDied, with the end of its log
            if time.monotonic() > deadline:
                raise RuntimeError(f"waited {READY_TIMEOUT_S:g} s for {what}")
            time.sleep(0.1)

    # -- running and after ------------------------------------------------------------------
    def pids(self) -> dict[str, int]:
        return {name: p.pid for name, p in self.session.procs.items() if p.poll() is None}

    def browser_records(self) -> list[dict]:
        """What each browser process saw (written when it ended)."""
        records = []
        for name in self.clients:
            path = self.workdir / f"{name}.json"
            if name.startswith("browsers") and path.exists():
                records.append(json.loads(path.read_text()))
        return records

    def service_counters(self) -> dict[str, dict[str, int]]:
        """Each service's last counters of what it missed or dropped (its JSON log lines)."""
        return {name: _missed(self.workdir / f"{name}.log") for name in self.services}

    def stop(self) -> None:
        """The browsers and teachers first (they write what they saw), the harness's node,
        then the services in reverse and the router last; SIGTERM, SIGKILL after a grace."""
        for name in reversed(self.clients):
            if name in self.session.procs:
                self.session.end(name)
        self.probe.stop()
        self.session.stop()


def _missed(log: Path) -> dict[str, int]:
    try:
        lines = log.read_text().splitlines()
    except OSError:
        return {}
    return {k: v for k, v in last_counters(lines).items() if k.startswith(MISSED)}


def _serving(port: int) -> bool:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=2) as r:
            return r.status == 200
    except OSError:
        return False

"""The harness's session: `voxshape up` (the launcher) in a working directory of its own, plus
one simulated teacher per robot (`voxshape sim-teacher`, speaking through the speech service).

The launcher restarts a service that dies, as compose's `restart` says; the harness follows
the pids it prints, so that the monkey (monkey.py) can hit the services and check the
restarts. Every process it starts is ended by pid.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path

from benchmarks.common import ROOT, last_counters
from voxshape.runtime import BusConfig, free_loopback_port
from voxshape.runtime.processes import end_process

VOXSHAPE = str(Path(sys.executable).parent / "voxshape")
STOP_TIMEOUT_S = 120.0  # `voxshape up` stops services in turn, 10 s of grace each


def teacher_name(robot: str) -> str:
    return f"teacher-{robot}"


class Session:
    """`voxshape up` in `workdir` plus a simulated teacher per robot."""

    def __init__(
        self,
        workdir: Path,
        robots: tuple[str, ...],
        rtf: float,
        session_id: str = "chaos",
        seed: int = 0,
        teacher_profile: str = "person",
    ) -> None:
        self.workdir, self.robots, self.rtf, self.session_id = workdir, robots, rtf, session_id
        self.seed, self.profile = seed, teacher_profile
        self.port = free_loopback_port()
        self.router = f"tcp/127.0.0.1:{self.port}"
        self.run_dir = workdir / "runs" / session_id
        self.lines: list[str] = []  # the launcher's output, as relayed
        self.pids: dict[str, int] = {}  # service -> pid of its current process
        self.starts: dict[str, list[tuple[float, int]]] = defaultdict(list)  # (time, pid)
        self.ready = threading.Event()
        self.up: subprocess.Popen | None = None
        self.teachers: dict[str, subprocess.Popen] = {}
        self._lock = threading.Lock()
        self.started_at = 0.0

    def env(self) -> dict[str, str]:
        inherited = {k: v for k, v in os.environ.items() if not k.startswith("VOXSHAPE_")}
        return {
            **inherited,
            "PYTHONUNBUFFERED": "1",
            "VOXSHAPE_SESSION": self.session_id,
            "VOXSHAPE_SPEECH_ENGINE": "mock",
            "VOXSHAPE_CLOCK": "paced",
            "VOXSHAPE_LOG_FORMAT": "json",
            # the simulated teachers' delays are robot seconds (voxshape/lab/demo.py)
            "VOXSHAPE_ROBOT_TIME": ",".join(teacher_name(r) for r in self.robots),
            "VOXSHAPE_VIEWER_PORT": str(free_loopback_port()),
            "VOXSHAPE_VIEWER_BIND": "127.0.0.1",
            "VOXSHAPE_WEB_PORT": str(free_loopback_port()),
            "VOXSHAPE_WEB_ADDRESS": "127.0.0.1",
        }

    def client_config(self, node: str) -> BusConfig:
        """The bus settings of a node of the harness, a client of the session's router."""
        return BusConfig(
            session=self.session_id,
            node=node,
            mode="client",
            connect=(self.router,),
            connect_timeout=10.0,
        ).validated()

    def start(self, timeout: float = 120.0) -> None:
        self.workdir.mkdir(parents=True, exist_ok=True)
        argv = [VOXSHAPE, "up", "--compose", str(ROOT / "compose.yaml"), "--port", str(self.port)]
        argv += ["--rtf", f"{self.rtf:g}", "--robots", ",".join(self.robots)]
        argv += ["--ready-timeout", "60"]
        self.up = subprocess.Popen(
            argv,
            cwd=self.workdir,
            env=self.env(),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )
        threading.Thread(target=self._read, daemon=True).start()
        if not self.ready.wait(timeout) or self.up.poll() is not None:
            raise RuntimeError("the session did not start:\n" + "\n".join(self.lines[-40:]))
        self.started_at = time.monotonic()
        for i, robot in enumerate(self.robots):
            self.teachers[robot] = self._teacher(robot, self.seed + i)

    def _teacher(self, robot: str, seed: int) -> subprocess.Popen:
        name = teacher_name(robot)
        argv = [VOXSHAPE, "sim-teacher", "--seed", str(seed), "--teacher-profile", self.profile]
        argv += ["--session", self.session_id, "--node", name, "--mode", "client"]
        argv += ["--connect", self.router, "--robot", robot, "--teacher", name]
        log = open(self.workdir / f"{name}.log", "w")  # noqa: SIM115 (closed with the process)
        return subprocess.Popen(
            argv,
            cwd=self.workdir,
            env=self.env(),
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )

    def _read(self) -> None:
        assert self.up is not None and self.up.stdout is not None
        with open(self.workdir / "up.log", "w") as copy:
            for line in self.up.stdout:
                line = line.rstrip("\n")
                copy.write(line + "\n")
                copy.flush()
                with self._lock:
                    self.lines.append(line)
                name, _, text = line.partition(" | ")
                if name.strip() == "up":
                    if text.startswith("started ") and "(pid " in text:
                        service = text.split()[1]
                        pid = int(text.split("(pid ", 1)[1].split(")", 1)[0])
                        self.pids[service] = pid
                        self.starts[service].append((time.monotonic(), pid))
                    elif text.startswith("ready in "):
                        self.ready.set()

    def alive(self, service: str) -> bool:
        pid = self.pids.get(service)
        return pid is not None and pid_alive(pid)

    def children(self, pid: int) -> list[int]:
        """The child processes of `pid` (the logger's renderer)."""
        try:
            tasks = Path(f"/proc/{pid}/task").iterdir()
            found = []
            for task in tasks:
                text = (task / "children").read_text().split()
                found += [int(c) for c in text]
            return found
        except OSError:
            return []

    def memory(self) -> dict[str, int]:
        """Resident memory (VmRSS, kB) of each service, the renderer and each teacher."""
        out = {}
        for service, pid in sorted(self.pids.items()):
            out[service] = rss_kb(pid)
            for child in self.children(pid):
                out[f"{service}.child"] = out.get(f"{service}.child", 0) + rss_kb(child)
        for robot, proc in self.teachers.items():
            out[teacher_name(robot)] = rss_kb(proc.pid)
        return out

    def stop(self) -> tuple[int | None, dict[str, dict], dict[str, dict]]:
        """Stops the teachers, then the session; the launcher's exit code, each service's
        last counters and each teacher's."""
        teacher_counters = {}
        for robot, proc in self.teachers.items():
            end_process(proc, 30)
            text = (self.workdir / f"{teacher_name(robot)}.log").read_text()
            teacher_counters[robot] = last_counters(text.splitlines())
        code = None if self.up is None else end_process(self.up, STOP_TIMEOUT_S)
        time.sleep(0.5)  # the reader thread takes the last lines
        with self._lock:
            lines = list(self.lines)
        by_service: dict[str, list[str]] = defaultdict(list)
        for line in lines:
            name, _, text = line.partition(" | ")
            by_service[name.strip()].append(text)
        counters = {s: last_counters(texts) for s, texts in by_service.items()}
        return code, counters, teacher_counters

    def kill_all(self) -> None:
        """Ends whatever is left (by pid): for a harness that failed halfway."""
        procs = [*self.teachers.values(), *([self.up] if self.up else [])]
        for proc in procs:
            if proc.poll() is None:
                os.kill(proc.pid, signal.SIGKILL)
                proc.wait(10)
        for pid in self.pids.values():
            if pid_alive(pid):
                for child in self.children(pid):
                    _signal(child, signal.SIGKILL)
                _signal(pid, signal.SIGCONT)
                _signal(pid, signal.SIGKILL)


def pid_alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


def _signal(pid: int, sig: int) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, sig)


def rss_kb(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0

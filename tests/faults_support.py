"""What the fault tests share: the services they start and stop, and what they read of
their logs (tests/test_faults*.py)."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import numpy as np

from tests.conftest import VOXSHAPE, bus_args, wait_for_port
from voxshape.launcher import router_command

JSON_LOGS = {**os.environ, "VOXSHAPE_LOG_FORMAT": "json"}


RTF = 5.0  # the paced simulator's speed: 50 steps/s


# From present on the bus to stepping: a simulator loads PyBullet and its map after it joins;
# a loaded machine (a clean clone's first run beside other work) took more than 10 s.
STARTING_S = 60.0


def figures(fault: str, **values: object) -> None:
    print("FAULT-FIGURES " + json.dumps({"fault": fault, **values}), flush=True)


def service(spawn, role: str, router: str, session_id: str, node: str, *args: str, **kw):
    kw.setdefault("env", JSON_LOGS)
    return spawn([VOXSHAPE, role, *bus_args(router, session_id, node), *args], text=True, **kw)


def teach_as_ana(spawn, router: str, session_id: str, *args: str, **kw):
    """`voxshape teach` as ana, to r1, its lines as JSON, with `args` besides."""
    ana = ("--teacher", "ana", "--robot", "r1", "--json")
    return service(spawn, "teach", router, session_id, "teach", *ana, *args, **kw)


def paced_sim(spawn, router, session_id):
    return service(spawn, "sim", router, session_id, "sim", "--rtf", str(RTF), "--seed", "0")


def stop(proc: subprocess.Popen, timeout: float = 30.0) -> tuple[int, dict, str]:
    """SIGTERM, then its exit code, its last counters and its stderr."""
    proc.send_signal(signal.SIGTERM)
    return finish(proc, timeout)


def finish(proc: subprocess.Popen, timeout: float = 30.0) -> tuple[int, dict, str]:
    """Its exit code, its last counters and its stderr, once it has ended."""
    _, err = proc.communicate(timeout=timeout)
    return proc.returncode, last_counters(err), err


def last_counters(stderr: str) -> dict:
    found: dict = {}
    for line in stderr.splitlines():
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:
            continue
        if entry.get("message") == "counters":
            found = {k: v for k, v in entry.items() if k not in ("time", "level", "logger")}
    return found


def log_entries(stderr: str, message: str) -> list[dict]:
    out = []
    for line in stderr.splitlines():
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:
            continue
        if entry.get("message") == message:
            out.append(entry)
    return out


def checkpoint_meta(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as data:
        return json.loads(str(data["meta"]))


# -- the learner killed mid-training ----------------------------------------------------------
def learner(spawn, router, session_id, path: Path, every: float):
    return service(
        spawn,
        "learner",
        router,
        session_id,
        "learner",
        *("--checkpoint", str(path), "--checkpoint-every", str(every), "--seed", "0"),
    )


# -- the router killed and restarted -----------------------------------------------------------
def start_router(spawn, session_id: str, endpoint: str) -> subprocess.Popen:
    proc = spawn(
        router_command("--session", session_id, "--node", "router", "--listen", endpoint),
        text=True,
        env=JSON_LOGS,
    )
    wait_for_port(int(endpoint.rsplit(":", 1)[1]))
    return proc


# -- the speech service killed ---------------------------------------------------------------
class Lines:
    """A child's JSON stdout lines as they come, with their arrival time (a thread reads)."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.got: list[tuple[float, dict]] = []
        self._thread = threading.Thread(target=self._read, args=(proc,), daemon=True)
        self._thread.start()

    def _read(self, proc: subprocess.Popen) -> None:
        for line in proc.stdout:
            with contextlib.suppress(json.JSONDecodeError):
                self.got.append((time.monotonic(), json.loads(line)))

    def wait_for(self, event: str, timeout: float = 15.0, **match: object) -> tuple[float, dict]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for at, entry in list(self.got):
                if entry.get("event") == event and all(entry.get(k) == v for k, v in match.items()):
                    return at, entry
            time.sleep(0.02)
        raise AssertionError(f"no {event} {match} within {timeout} s: {self.got}")


OUTAGE_S = 10.0  # how long a service stays down in the outage tests


class Typist:
    """`voxshape teach` typing good and bad in turn, 0.3 s apart."""

    def __init__(self, teach: subprocess.Popen) -> None:
        self.teach, self.typed = teach, 0

    def say(self, n: int) -> None:
        for _ in range(n):
            self.type("good" if self.typed % 2 else "bad")
            time.sleep(0.3)

    def type(self, word: str) -> None:
        self.teach.stdin.write(f"{word}\n")
        self.teach.stdin.flush()
        self.typed += 1

    def shown(self) -> list[dict]:
        """What it showed, once its input is closed."""
        self.teach.stdin.close()
        self.teach.wait(30)
        return [json.loads(line) for line in self.teach.stdout.read().splitlines()]


def typist(spawn, endpoint: str, session_id: str, cwd: Path, linger: float = 4) -> Typist:
    """`voxshape teach` as ana, to r1, its lines as JSON; it stays `linger` s after its input."""
    teach = teach_as_ana(
        spawn, endpoint, session_id, "--linger", str(linger),
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, cwd=cwd,
    )  # fmt: skip
    return Typist(teach)

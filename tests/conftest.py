"""Fixtures for tests on a real bus: free loopback ports, a real router process, and child
processes that are always ended (by pid) when the test is over."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path

import pytest

from services.deploy.access import load_access
from services.deploy.certs import make_all
from services.launcher import router_command
from services.runtime import BusConfig, Input, Node, Presence, bus_config
from services.runtime import free_loopback_port as free_port
from services.runtime.config import wait_for_loopback_port as wait_for_port
from services.runtime.processes import end_process

ROOT = Path(__file__).resolve().parents[1]
VOXSHAPE = str(Path(sys.executable).parent / "voxshape")


def read_until(
    proc: subprocess.Popen,
    pattern: str,
    timeout: float = 30.0,
    stream: str = "stdout",
    seen: list[str] | None = None,
) -> list[str]:
    """Lines of `proc`'s `stream` (a text pipe) up to the first matching `pattern`, appended
    to `seen` if given (fails after `timeout`, or when the process ends first)."""
    lines = [] if seen is None else seen
    pipe = getattr(proc, stream)
    os.set_blocking(pipe.fileno(), False)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = pipe.readline()
        if line:
            lines.append(line.rstrip())
            if re.search(pattern, line):
                return lines
        elif proc.poll() is not None:
            break
        else:
            time.sleep(0.05)
    pytest.fail(f"no line matching {pattern!r} within {timeout} s:\n" + "\n".join(lines))


@pytest.fixture
def session_id() -> str:
    return f"t{uuid.uuid4().hex[:10]}"


@pytest.fixture
def spawn() -> Iterator[Callable[..., subprocess.Popen]]:
    """Starts a child process; every child still running at the end is stopped by its pid."""
    children: list[subprocess.Popen] = []

    def start(argv: list[str], **kwargs: object) -> subprocess.Popen:
        kwargs.setdefault("stdout", subprocess.PIPE)
        kwargs.setdefault("stderr", subprocess.PIPE)
        kwargs.setdefault("cwd", ROOT)
        proc = subprocess.Popen(argv, **kwargs)
        children.append(proc)
        return proc

    yield start
    for proc in children:
        end_process(proc, 10, 5)


@pytest.fixture
def router(spawn, session_id) -> str:
    """A real `voxshape router` on a free loopback port; returns its endpoint."""
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    spawn(router_command("--session", session_id, "--node", "router", "--listen", endpoint))
    wait_for_port(port)
    return endpoint


@pytest.fixture
def client_config(router, session_id) -> Callable[[str], BusConfig]:
    """Bus configuration of an in-test node that is a client of the test's router."""

    def make(node: str) -> BusConfig:
        return replace(
            bus_config("test", env={}),
            session=session_id,
            node=node,
            mode="client",
            connect=(router,),
            connect_timeout=5.0,
        )

    return make


def bus_args(router: str, session_id: str, node: str) -> list[str]:
    return ["--session", session_id, "--node", node, "--mode", "client", "--connect", router]


def collect(node: Node, n: int, kind: type | tuple[type, ...], timeout: float = 15.0) -> list:
    """The next `n` messages of one type, or of any of several (others are skipped). Zenoh
    orders messages per key only: collect messages on different keys together."""
    got, deadline = [], time.monotonic() + timeout
    while len(got) < n and time.monotonic() < deadline:
        event = node.poll(0.1)
        if isinstance(event, Input) and isinstance(event.message, kind):
            got.append(event.message)
    assert len(got) == n, f"got {len(got)} of {n} {kind} within {timeout} s"
    return got


def wait_present(node: Node, names: set[str] | str, timeout: float = 30.0) -> None:
    """Until every named node has announced itself (the node watches presence), then a moment
    for their subscriptions to reach the router with their tokens."""
    names = {names} if isinstance(names, str) else names
    present: set[str] = set()
    deadline = time.monotonic() + timeout
    while not names <= present and time.monotonic() < deadline:
        event = node.poll(0.1)
        if isinstance(event, Presence) and event.alive:
            present.add(event.node)
    assert names <= present, f"not present after {timeout} s: {sorted(names - present)}"
    time.sleep(0.5)


def quiet(node: Node, seconds: float) -> list:
    """Everything that arrives within `seconds`."""
    got, deadline = [], time.monotonic() + seconds
    while time.monotonic() < deadline:
        event = node.poll(0.05)
        if isinstance(event, Input):
            got.append(event.message)
    return got


SECURED_ACCESS = """
[users]
logger = { role = "admin" }
arbiter = { role = "arbiter" }
web = { role = "observer" }
ana = { role = "teacher" }
ben = { role = "teacher" }
cy = { role = "teacher" }
"""


@pytest.fixture
def secured(tmp_path, spawn) -> tuple[str, Path]:
    """A router with passwords and access control; its endpoint and the secrets folder."""
    access = tmp_path / "access.toml"
    access.write_text(SECURED_ACCESS)
    make_all(tmp_path, load_access(access))
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    spawn(
        router_command(
            *("--session", "secured", "--node", "router"),
            *("--secrets", str(tmp_path), "--access", str(access), "--listen", endpoint),
        )
    )
    wait_for_port(port)
    return endpoint, tmp_path

"""Fixtures for tests on a real bus: free loopback ports, a real router process, and child
processes that are always ended (by pid) when the test is over. The suite runs in parallel
(pytest-xdist): each worker takes its ports from a range of its own, and every test its own
session id and folders."""

from __future__ import annotations

import os
import random
import re
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path

import pytest

from voxshape.deploy.access import load_access
from voxshape.deploy.certs import make_all
from voxshape.launcher import router_command
from voxshape.runtime import BusConfig, Input, Node, Presence, bus_config, free_loopback_port
from voxshape.runtime.config import wait_for_loopback_port as wait_for_port
from voxshape.runtime.processes import end_process

ROOT = Path(__file__).resolve().parents[1]
VOXSHAPE = str(Path(sys.executable).parent / "voxshape")

# The tests' ports lie between this and the kernel's ephemeral range: above the well-known
# ports, zenoh's 7447, the page's 8080, the viewer's 9876 and Ray's workers (10002-19999).
LOWEST_PORT = 20000
_given: set[int] = set()  # ports this process handed out: never twice


def _ephemeral_range() -> tuple[int, int]:
    try:
        low, high = Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()
        return int(low), int(high)
    except (OSError, ValueError):
        return 32768, 60999  # Linux's default


def _worker_ports() -> range:
    """This xdist worker's share of the ports below the ephemeral range (all of them when
    the suite runs in one process)."""
    top = _ephemeral_range()[0]
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    index = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw") or 0)
    share = (top - LOWEST_PORT) // max(workers, 1)
    start = LOWEST_PORT + (index % max(workers, 1)) * share
    return range(start, start + share)


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now and that no other worker of this
    run is given: from this worker's range, below the kernel's ephemeral ports, so that no
    outgoing connection or bind(0) takes it before the child that was given it listens."""
    ports = _worker_ports()
    if len(ports) < 200:  # an unusual ephemeral range: any free port
        return free_loopback_port()
    for _ in range(200):
        port = random.choice(ports)
        if port not in _given and _bindable(port):
            _given.add(port)
            return port
    raise RuntimeError(f"no free port among 200 tries in {ports}")


def _bindable(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The long tests first (in their order, then the others in theirs): a parallel run
    spreads them over its workers from the start instead of ending on one of them."""
    items.sort(key=lambda item: item.get_closest_marker("long") is None)
    if getattr(config.option, "loadgroup", False):  # an xdist worker of `--dist loadgroup`
        for item in items:
            _name_xdist_group(item)


def _name_xdist_group(item: pytest.Item) -> None:
    """What pytest-xdist 3.8 does for `--dist loadgroup`: the item's xdist_group appended to
    its node id ("...::test_x@cluster"), which the scheduler keeps on one worker. xdist sets
    `item._nodeid`, which pytest 9.2 no longer reads (its ids are `item._id`), so its groups
    are lost; done here unless xdist did it."""
    names = {str(m.args[0] if m.args else m.kwargs.get("name", "default"))
             for m in item.iter_markers("xdist_group")}  # fmt: skip
    if names and "@" not in item.nodeid and hasattr(item, "_id"):
        from _pytest.nodeid import NodeId  # pytest 9.2's, as item._id is

        item._id = NodeId.parse(f"{item.nodeid}@{'_'.join(sorted(names))}")


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


def web_log_path(port: int) -> Path:
    """Where a test's `voxshape web` on `port` writes its output: named by the port and this
    process, so that no other test or concurrent run writes the same file."""
    return Path(os.environ.get("TMPDIR", "/tmp")) / f"voxshape-web-{port}-{os.getpid()}.log"


def seconds_to_start(env: dict[str, str]) -> float:
    """How long `voxshape teach` takes to start and parse its arguments on this machine now:
    the reference for a test that times a client from its start, on a loaded machine too."""
    started = time.monotonic()
    subprocess.run([VOXSHAPE, "teach", "--help"], env=env, capture_output=True, check=True)
    return time.monotonic() - started


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

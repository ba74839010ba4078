"""Runs of an experiment as Ray tasks on a cluster (`voxshape experiment paper|sweep --cluster`).

Each run is one Ray task of `inprocess.run`, one CPU each. A task whose worker process or node
is lost is retried by Ray (`MAX_RETRIES`); an exception the run itself raises is not retried
(runs are deterministic per seed: it would fail again) and comes back as the run's failure.
Workers import the code from their own installation of voxshape (docs/experiments.md, "On a
cluster"): nothing is shipped with the tasks.

`LocalCluster` starts a Ray cluster of a head and worker nodes on this machine's loopback
(the tests and benchmarks/cluster.py use it) and ends every process it started.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import ModuleType

from voxshape.lab.experiment.inprocess import RunResult, RunSpec, run

MAX_RETRIES = 3  # a run is tried again this many times when its worker or node is lost
INSTALL = "pip install 'voxshape[cluster]'"
RAY_CLIENT_PORT = 10001  # Ray Client's default port (ray://HOST)


class ClusterError(RuntimeError):
    """No Ray, or no cluster at the address: the message names the address and the fix."""


def _ray() -> ModuleType:
    try:
        import ray
    except ImportError:
        raise ClusterError(f"--cluster runs on Ray, which is not installed: {INSTALL}") from None
    return ray


def _host_port(ray: ModuleType, address: str) -> tuple[str, int] | None:
    """The host and port an address names; for `auto`, the cluster Ray would pick (RAY_ADDRESS,
    the last `ray start` on this machine; None if Ray's way of finding it has changed)."""
    if address == "auto":
        try:
            address = ray._private.services.get_ray_address_from_environment("auto", None)
        except ConnectionError as e:
            raise ClusterError(
                "no Ray cluster found for --cluster auto on this machine: start one with "
                "`ray start --head` or give its address to --cluster"
            ) from e
        except Exception:
            return None
        if address == "auto":
            return None
    bare = address.removeprefix("ray://")
    host, _, port = bare.rpartition(":")
    if not host:  # ray://HOST: Ray Client's default port; HOST alone: the GCS's
        return bare, RAY_CLIENT_PORT if address.startswith("ray://") else 6379
    try:
        return host.strip("[]"), int(port)
    except ValueError:
        raise ClusterError(
            f"--cluster {address}: not auto, ray://HOST:PORT nor HOST:PORT"
        ) from None


def connect(address: str, timeout: float = 5.0) -> ModuleType:
    """Connects this process to the Ray cluster at `address` (`auto`, `ray://HOST:10001` or
    the head's GCS, `HOST:6379`); returns the ray module. Ray waits a minute or more for a GCS
    that is not there, so the address is first tried with a plain TCP connection."""
    ray = _ray()
    fix = "start one with `ray start --head` or check --cluster"
    host_port = _host_port(ray, address)
    if host_port is not None:
        try:
            socket.create_connection(host_port, timeout=timeout).close()
        except OSError as e:
            where = f"{address} ({host_port[0]}:{host_port[1]})" if address == "auto" else address
            raise ClusterError(f"no Ray cluster at {where}: {fix} ({e})") from None
    try:
        ray.init(address=address, log_to_driver=False, logging_level="WARNING")
    except (ConnectionError, RuntimeError, ValueError) as e:
        raise ClusterError(f"no Ray cluster at {address}: {fix} ({e})") from None
    return ray


def failure(error: BaseException) -> str:
    """A run's failure in a line: the run's own exception, or what Ray lost."""
    cause = getattr(error, "cause", None)  # RayTaskError: the exception the run raised
    error = cause if isinstance(cause, BaseException) else error
    text = str(error).strip().splitlines()
    return f"{type(error).__name__}: {text[0] if text else ''}".rstrip(": ")


def on_ray(
    specs: Sequence[RunSpec], reference: bool, address: str
) -> Iterator[tuple[int, RunResult | BaseException]]:
    """Each run as a Ray task on the cluster at `address`: (index in `specs`, its result or
    the error it failed with for good), as they finish; connects at once (ClusterError) and
    disconnects once the runs are done."""
    ray = connect(address)
    return _tasks(ray, specs, reference)


def _tasks(
    ray: ModuleType, specs: Sequence[RunSpec], reference: bool
) -> Iterator[tuple[int, RunResult | BaseException]]:
    try:
        task = ray.remote(num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False)(run)
        refs = {task.remote(spec, reference): i for i, spec in enumerate(specs)}
        pending = list(refs)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                try:
                    yield refs[ref], ray.get(ref)
                except ray.exceptions.RayError as e:
                    yield refs[ref], e
    finally:
        ray.shutdown()


# Ray resolves 127.0.0.1 to the machine's network address; a cluster for tests keeps to
# the loopback, so its nodes are started with that resolution turned off.
_LOOPBACK_RAY = (
    "import sys, ray._private.services as s; s.resolve_ip_for_localhost = lambda h: h; "
    "from ray.scripts.scripts import main; sys.argv[0] = 'ray'; main()"
)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def workers_of(node: subprocess.Popen) -> dict[int, str]:
    """The Ray workers of a node, by pid, with their titles (`ray::run` while running the task
    `run`, `ray::IDLE` between tasks): children of its daemons, each in a session of its own."""
    workers = {}
    for proc in Path("/proc").iterdir():
        try:
            parent = int((proc / "stat").read_text().rsplit(")", 1)[1].split()[1])
            if os.getpgid(parent) == node.pid and os.getpgid(int(proc.name)) != node.pid:
                workers[int(proc.name)] = (proc / "cmdline").read_bytes().split(b"\0")[0].decode()
        except (ValueError, OSError, IndexError):
            continue
    return workers


def _signal_group(node: subprocess.Popen, sig: int) -> None:
    """Signals a node's process group (its `ray start` and the daemons it started) and its
    workers."""
    workers = workers_of(node)
    with contextlib.suppress(ProcessLookupError):
        os.killpg(node.pid, sig)
    for pid in workers:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, sig)


class LocalCluster:
    """A Ray head and `workers` worker nodes on 127.0.0.1, `cpus` CPUs each, every node a
    `ray start --block` child in its own process group (its daemons with it), ended by
    `stop`. `address` is the head's GCS; a driver connecting to it from this machine needs
    `driver_env` (keeps Ray's own resolution on the loopback too)."""

    def __init__(self, workers: int = 1, cpus: int = 1, timeout: float = 60.0) -> None:
        self.port = _free_port()
        self.address = f"127.0.0.1:{self.port}"
        self.client_port = _free_port()  # Ray Client's: ray://127.0.0.1:client_port
        self.temp_dir = tempfile.mkdtemp(prefix="vxray")  # short: Ray's socket paths live here
        self.nodes: list[subprocess.Popen] = []
        self.cpus, self.timeout = cpus, timeout
        try:
            self._start(["--head", "--port", str(self.port), "--include-dashboard", "false",
                         "--dashboard-port", str(_free_port()),
                         "--ray-client-server-port", str(self.client_port)],
                        head=True)  # fmt: skip
            self.wait_for_nodes(1)
            for _ in range(workers):
                self.add_worker()
        except BaseException:
            self.stop()
            raise

    @property
    def driver_env(self) -> dict[str, str]:
        return {**os.environ, "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}

    def _start(self, arguments: list[str], head: bool = False) -> subprocess.Popen:
        command = [sys.executable, "-c", _LOOPBACK_RAY, "start", "--block",
                   "--node-ip-address", "127.0.0.1", "--num-cpus", str(self.cpus),
                   "--disable-usage-stats", "--temp-dir", self.temp_dir,
                   "--dashboard-agent-listen-port", str(_free_port()), *arguments]  # fmt: skip
        log = open(os.path.join(self.temp_dir, f"node-{len(self.nodes)}.log"), "wb")  # noqa: SIM115
        # Ray runs tasks at nice 15 by default: on a machine shared with other work they
        # would wait for it, where the local pool's processes do not.
        env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_worker_niceness": "0"}
        if head:  # its daemons (Ray Client's servers) resolve addresses too
            env["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
        node = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=env,
                                start_new_session=True)  # fmt: skip
        log.close()
        self.nodes.append(node)
        return node

    def add_worker(self) -> subprocess.Popen:
        """Starts one more worker node and waits until the head counts it."""
        node = self._start(["--address", self.address])
        self.wait_for_nodes(len(self.nodes))
        return node

    def alive_nodes(self) -> int:
        """Nodes the head counts as alive (`ray list nodes`' state), through a driver."""
        code = (
            f"import ray; ray.init(address={self.address!r}, logging_level='ERROR', "
            "log_to_driver=False); print(sum(n['Alive'] for n in ray.nodes()))"
        )
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              env=self.driver_env, timeout=self.timeout)  # fmt: skip
        return int(done.stdout.split()[-1]) if done.returncode == 0 and done.stdout else 0

    def wait_for_nodes(self, count: int) -> None:
        deadline = time.monotonic() + self.timeout
        while time.monotonic() < deadline:
            for node in self.nodes:
                if node.poll() is not None:
                    raise RuntimeError(f"ray start exited with {node.returncode}: {self._log()}")
            if self._port_open() and self.alive_nodes() >= count:
                return
            time.sleep(0.5)
        raise TimeoutError(f"{count} Ray nodes not up after {self.timeout} s: {self._log()}")

    def _port_open(self) -> bool:
        with socket.socket() as s:
            return s.connect_ex(("127.0.0.1", self.port)) == 0

    def _log(self) -> str:
        path = os.path.join(self.temp_dir, f"node-{len(self.nodes) - 1}.log")
        with open(path, errors="replace") as f:
            return f.read()[-2000:]

    def kill(self, node: subprocess.Popen) -> None:
        """Ends a node at once, every process of its group (a lost machine)."""
        _signal_group(node, signal.SIGKILL)
        node.wait(timeout=10)

    def stop(self) -> None:
        """Ends every node this cluster started (their process groups, by pid)."""
        for node in reversed(self.nodes):
            _signal_group(node, signal.SIGTERM)
        deadline = time.monotonic() + 2
        for node in self.nodes:
            with contextlib.suppress(subprocess.TimeoutExpired):
                node.wait(timeout=max(0.1, deadline - time.monotonic()))
            _signal_group(node, signal.SIGKILL)  # daemons that outlived their `ray start`
            node.wait(timeout=10)
        shutil.rmtree(self.temp_dir, ignore_errors=True)

    def __enter__(self) -> LocalCluster:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

"""Sessions of their own for the benchmarks, the experiments and the test harnesses.

A `LoopbackSession` is a LocalSession on a free loopback port, with its caller's session id:
compose.yaml's router (what `start()` starts), then the services of compose.yaml the caller
adds (`service()`, with arguments of its own) and processes of its own that join the session
(`client()`: a simulated teacher, a harness's browsers). Nothing is restarted: a process that
dies stops the session with an error naming it and quoting the end of its log.

    with LoopbackSession("bench-1", variables={"VOXSHAPE_SPEECH_ENGINE": "mock"}) as session:
        session.add(session.service("arbiter"), session.service("speech", "--latency", "0"))
        with Node("bench", session.client_config("bench")) as node:
            ...
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from types import TracebackType

from voxshape.launcher.session import LocalSession
from voxshape.launcher.topology import (
    ServiceSpec,
    TopologyError,
    find_compose_file,
    load_topology,
    local_variables,
)
from voxshape.runtime import BusConfig, free_loopback_port


class LoopbackSession(LocalSession):
    """compose.yaml's router on a free loopback port, and what its caller adds to it."""

    def __init__(
        self,
        session_id: str,
        *,
        variables: Mapping[str, str] | None = None,
        logs: Path | None = None,
        cwd: Path | None = None,
        ready_timeout: float = 60.0,
    ) -> None:
        """`variables`: compose.yaml's (VOXSHAPE_TASK, VOXSHAPE_SPEECH_ENGINE...) over the
        local ones (not the shell's), also given to every process of the session. `logs`: a
        folder for each process's <name>.log (else their output is relayed to stdout)."""
        endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
        given = dict(variables or {})
        session = {"VOXSHAPE_SESSION": session_id}
        router = {"VOXSHAPE_ROUTER": endpoint, "VOXSHAPE_ROUTER_LISTEN": endpoint}
        interpolated = {**local_variables({}), **given, **session, **router}
        self.topology = {s.name: s for s in load_topology(find_compose_file(), interpolated)}
        if logs is not None:
            logs.mkdir(parents=True, exist_ok=True)
        super().__init__(
            [self.topology["router"]],
            endpoint,
            ready_timeout,
            restart=False,
            logs=logs,
            cwd=cwd,
            environment=given,
        )

    def __enter__(self) -> LoopbackSession:
        try:
            self.start()
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        self.stop()

    def service(self, name: str, *arguments: str, named: str | None = None) -> ServiceSpec:
        """compose.yaml's service `name` in this session, `arguments` after its command;
        `named`: another name and node id for it (a second simulator)."""
        spec = self.topology.get(name)
        if spec is None:
            raise TopologyError(
                f"compose.yaml has no service {name!r} to run by default; it has "
                f"{', '.join(self.topology)} (another process: client())"
            )
        renamed = {} if named is None else {"VOXSHAPE_NODE": named}
        return replace(
            spec,
            name=named or name,
            command=(*spec.command, *arguments),
            environment={**spec.environment, **renamed},
        )

    def client(
        self,
        name: str,
        command: Sequence[str],
        *,
        after: tuple[str, ...] = ("router",),
        on_bus: bool = True,
        environment: Mapping[str, str] | None = None,
    ) -> ServiceSpec:
        """A process of the caller's that joins the session as node `name`, a client of its
        router: this installation's `voxshape ...`, or another program (`on_bus=False`: it
        announces no presence; it is up once started). It starts once `after` are present."""
        bus = {
            "VOXSHAPE_SESSION": self.session_id,
            "VOXSHAPE_MODE": "client",
            "VOXSHAPE_CONNECT": self.router,
            "VOXSHAPE_NODE": name,
        }
        return ServiceSpec(
            name, tuple(command), {**bus, **(environment or {})}, after, (), on_bus=on_bus
        )

    def client_config(self, node: str, connect_timeout: float = 10.0) -> BusConfig:
        """The bus settings of a node in the caller's own process, a client of the router."""
        return BusConfig(
            session=self.session_id,
            node=node,
            mode="client",
            connect=(self.router,),
            connect_timeout=connect_timeout,
        ).validated()

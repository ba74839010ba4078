"""The launcher: the one way a session is started.

session.py   LocalSession: a session's processes, started once their dependencies are present,
             restarted as their policy says, stopped by pid; the one place a router is spawned
up.py        `voxshape up` (and the demo's session): compose.yaml with the flags' variables
record.py    runs/<session>/launcher.json: a live session's launcher, router and pids
loopback.py  LoopbackSession: a session of its own on a free loopback port, for the
             benchmarks, the experiments and the test harnesses
"""

from voxshape.launcher.loopback import LoopbackSession
from voxshape.launcher.session import (
    LaunchAborted,
    LocalSession,
    ServiceDied,
    interrupt_on_stop_signals,
    resolve_command,
    router_command,
)
from voxshape.launcher.up import (
    add_arguments,
    add_up_arguments,
    local_session,
    prepare_run,
    run,
    session_variables,
    web_page,
    without_simulator,
)

__all__ = [
    "LaunchAborted",
    "LocalSession",
    "LoopbackSession",
    "ServiceDied",
    "add_arguments",
    "add_up_arguments",
    "interrupt_on_stop_signals",
    "local_session",
    "prepare_run",
    "resolve_command",
    "router_command",
    "run",
    "session_variables",
    "web_page",
    "without_simulator",
]

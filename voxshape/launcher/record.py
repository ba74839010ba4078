"""A live session's record, runs/<session>/launcher.json: which launcher runs it, on which
router, and each service's pid, so that a person who finds its port taken (or its processes
left over) is told whose they are and the one command that ends them.

The launcher writes it when a service starts (again) and removes it when the session stops;
a launcher killed outright leaves it behind, and its pids, gone by then, say so.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

from voxshape.runtime.config import tcp_address

RECORD_FILE = "launcher.json"


@dataclass
class SessionRecord:
    """runs/<session>/launcher.json of the launcher of session `session` on `router`."""

    path: Path
    session: str
    router: str
    launcher: int = field(default_factory=os.getpid)
    command: str = field(default_factory=lambda: " ".join(["voxshape", *sys.argv[1:2]]))
    services: dict[str, int] = field(default_factory=dict)

    def write(self, services: dict[str, int]) -> None:
        """Records the services' pids now (atomically: a reader never sees half of it)."""
        self.services = dict(services)
        data = {
            "session": self.session,
            "router": self.router,
            "launcher": self.launcher,
            "command": self.command,
            "services": self.services,
        }
        self.path.parent.mkdir(parents=True, exist_ok=True)
        part = self.path.with_name(f".{RECORD_FILE}.{os.getpid()}")
        part.write_text(json.dumps(data, indent=1) + "\n", "utf-8")
        part.replace(self.path)

    def remove(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()

    @classmethod
    def read(cls, path: Path) -> SessionRecord | None:
        """The record at `path`; None when there is none or it is not one."""
        try:
            data = json.loads(path.read_text("utf-8"))
            services = {str(k): int(v) for k, v in data["services"].items()}
            return cls(
                path, str(data["session"]), str(data["router"]), int(data["launcher"]),
                str(data["command"]), services,
            )  # fmt: skip
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            return None

    def alive(self) -> dict[str, int]:
        """Its processes still running: "launcher" and the services, by name."""
        every = {"launcher": self.launcher, **self.services}
        return {name: pid for name, pid in every.items() if running(pid)}

    def ending(self) -> str:
        """The one command that ends what is left of the session: SIGTERM to its launcher
        (which stops its services in order), else to the services left."""
        alive = self.alive()
        if "launcher" in alive:
            return f"kill {alive['launcher']}"
        return "kill " + " ".join(str(p) for p in alive.values()) if alive else ""

    def describe(self) -> str:
        """Whose the session is, in one line: its command, its pids, how to end it."""
        alive = self.alive()
        if not alive:
            return f"session {self.session!r} ({self.command}): none of its processes runs"
        pids = ", ".join(f"{name} {pid}" for name, pid in alive.items())
        return (
            f"session {self.session!r} ({self.command}, router {self.router}): pids {pids}; "
            f"end it with: {self.ending()}"
        )


def running(pid: int) -> bool:
    """Whether `pid` is a process that has not ended (a zombie has)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    except OSError:  # no /proc: ask the kernel
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            return True
        return True
    return stat.rsplit(")", 1)[-1].split()[0] not in ("Z", "X")


def records_in(runs: Path) -> list[SessionRecord]:
    """The records of runs/*/ whose processes still run."""
    found = (SessionRecord.read(p) for p in sorted(runs.glob(f"*/{RECORD_FILE}")))
    return [r for r in found if r is not None and r.alive()]


def holder_of(runs: Path, endpoint: str) -> SessionRecord | None:
    """The live session whose router listens where `endpoint` does (host and port), by its
    record in `runs`, if any."""
    where = tcp_address(endpoint)
    return next((r for r in records_in(runs) if tcp_address(r.router) == where), None)

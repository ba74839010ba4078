"""The monkey: kills (SIGKILL) or freezes (SIGSTOP, then SIGCONT) services by pid on a schedule,
and checks that the launcher restarted each killed one and left each frozen one alone.
"""

from __future__ import annotations

import os
import random
import signal
import time
from collections import Counter, defaultdict
from collections.abc import Callable
from dataclasses import dataclass

from benchmarks.harness.session import Session, pid_alive

SERVICES = ("router", "logger", "sim", "learner", "arbiter", "speech")  # what the monkey hits
FREEZE_S = 15.0  # longer than zenoh's lease (10 s): the frozen one's peers drop it


@dataclass(frozen=True)
class Fault:
    at: float  # seconds after the session started
    kind: str  # "kill" or "freeze"
    service: str


def random_schedule(seed: int, seconds: float, first: float = 20.0) -> list[Fault]:
    """A fault every 20-40 s (seeded), each a kill or a freeze of a random service."""
    rng = random.Random(seed)
    faults, at = [], first
    while at < seconds - 10:
        faults.append(Fault(at, rng.choice(("kill", "freeze")), rng.choice(SERVICES)))
        at += rng.uniform(20.0, 40.0)
    return faults


@dataclass
class Injected:
    fault: Fault
    pid: int
    ok: bool  # killed: restarted with a new pid; frozen: same pid alive, not restarted
    note: str = ""


class Monkey:
    """Injects a schedule of faults into a running session, one at a time, in this thread."""

    def __init__(self, session: Session, say: Callable[[str], None] = print) -> None:
        self.session, self.say = session, say
        self.injected: list[Injected] = []
        self.before_kill = lambda service: None  # e.g. to note what a learner's kill loses

    def run(self, schedule: list[Fault], until: float) -> None:
        """Injects each fault at its time (skipping one whose service is not running, e.g.
        awaiting its restart) until `until` seconds after the session started."""
        s = self.session
        for fault in schedule:
            if not self._sleep_until(s.started_at + fault.at, s.started_at + until):
                return
            if not s.alive(fault.service):
                self.say(f"[monkey] {fault.service} is not running: {fault.kind} skipped")
                continue
            pid = s.pids[fault.service]
            if fault.kind == "kill":
                self.injected.append(self._kill(fault, pid))
            else:
                self.injected.append(self._freeze(fault, pid))
        self._sleep_until(s.started_at + until, s.started_at + until)

    def _sleep_until(self, when: float, limit: float) -> bool:
        while time.monotonic() < min(when, limit):
            if self.session.up is not None and self.session.up.poll() is not None:
                raise RuntimeError("the session stopped:\n" + "\n".join(self.session.lines[-40:]))
            time.sleep(min(0.5, max(0.0, min(when, limit) - time.monotonic())))
        return when <= limit

    def _kill(self, fault: Fault, pid: int) -> Injected:
        s = self.session
        before = len(s.starts[fault.service])
        self._said("SIGKILL", fault.service, pid)
        self.before_kill(fault.service)
        os.kill(pid, signal.SIGKILL)  # its children live on: the renderer ends by itself
        deadline = time.monotonic() + 30
        while len(s.starts[fault.service]) == before and time.monotonic() < deadline:
            time.sleep(0.1)
        restarted = len(s.starts[fault.service]) > before
        return Injected(fault, pid, restarted, "" if restarted else "not restarted within 30 s")

    def _freeze(self, fault: Fault, pid: int) -> Injected:
        s = self.session
        before = len(s.starts[fault.service])
        self._said("SIGSTOP", fault.service, pid)
        os.kill(pid, signal.SIGSTOP)
        time.sleep(FREEZE_S)
        os.kill(pid, signal.SIGCONT)
        self._said("SIGCONT", fault.service, pid)
        time.sleep(1.0)
        ok = (
            pid_alive(pid)
            and len(s.starts[fault.service]) == before
            and s.pids[fault.service] == pid
        )
        note = "" if ok else "the launcher replaced a frozen service"
        return Injected(fault, pid, ok, note)

    def _said(self, what: str, service: str, pid: int) -> None:
        self.say(
            f"[monkey] {time.monotonic() - self.session.started_at:6.1f} s: {what} {service} {pid}"
        )

    def table(self) -> dict[tuple[str, str], int]:
        return Counter((i.fault.kind, i.fault.service) for i in self.injected)


def fault_table(monkey: Monkey) -> str:
    lines = ["| fault | service | injected | as expected |", "|---|---|---|---|"]
    grouped: dict[tuple[str, str], list[Injected]] = defaultdict(list)
    for i in monkey.injected:
        grouped[(i.fault.kind, i.fault.service)].append(i)
    for (kind, service), items in sorted(grouped.items()):
        ok = sum(i.ok for i in items)
        lines.append(f"| {kind} | {service} | {len(items)} | {ok} |")
    return "\n".join(lines)

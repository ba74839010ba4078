"""A session ends when its launcher ends, however it ends: a terminal closed (SIGHUP to its
group, its output gone), Ctrl-C twice, SIGTERM, or the launcher alone killed (SIGKILL).
Every process of the session is gone soon after, and the event log the logger kept reads
whole; `voxshape status` and a second `voxshape up` name a session that holds a port."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.conftest import VOXSHAPE, free_port, read_until
from voxshape.launcher.record import RECORD_FILE, SessionRecord, running
from voxshape.runtime.processes import ORPHAN_GRACE_S, PARENT_VARIABLE, ending_with_me
from voxshape.services.logger.eventlog import read_events

PIPE = subprocess.PIPE
# Whole sessions, one after another on one worker of a parallel run: seven services starting
# at once, four times over, would crowd the timing tests beside them.
SESSIONS = pytest.mark.xdist_group("sessions")
ENDED_WITHIN_S = 5.0  # what the design aims for; the test allows a loaded machine more
ENDED_BOUND_S = 30.0


def session_pids(session_id: str) -> set[int]:
    """The running processes of a session: those with its id in their environment (the
    services, and what they started: the logger's renderer)."""
    mark = f"VOXSHAPE_SESSION={session_id}".encode()
    found = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        with contextlib.suppress(OSError):
            if mark in (entry / "environ").read_bytes().split(b"\0") and running(int(entry.name)):
                found.add(int(entry.name))
    return found


@pytest.fixture
def ended(session_id) -> Iterator[str]:
    """A session id whose processes, any left when the test is over, are ended by pid."""
    yield session_id
    for pid in session_pids(session_id):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)


def start_session(spawn, session_id: str, cwd: Path, **popen: object) -> tuple:
    """`voxshape up` of `session_id` in `cwd` in a process group (and session) of its own, as
    a terminal's; ready, with the pids of its services and the router's port."""
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("VOXSHAPE_")}
    env["VOXSHAPE_WEB_PORT"] = str(free_port())
    argv = [VOXSHAPE, "up", "--port", str(port), "--session", session_id]
    popen = {"stderr": subprocess.STDOUT, "text": True, **popen}
    up = spawn(argv, env=env, cwd=cwd, start_new_session=True, **popen)
    lines = read_until(up, r"ready in", timeout=90)
    services = {int(m.group(1)) for line in lines if (m := re.search(r"\(pid (\d+)\)", line))}
    assert services and services <= session_pids(session_id), lines
    return up, port, lines


def wait_ended(session_id: str) -> float:
    """Seconds until no process of the session runs (fails past ENDED_BOUND_S, ending
    those left by pid)."""
    t0 = time.monotonic()
    while (left := session_pids(session_id)) and time.monotonic() - t0 < ENDED_BOUND_S:
        time.sleep(0.1)
    for pid in left:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    assert not left, f"left running after {ENDED_BOUND_S:g} s: {sorted(left)}"
    took = time.monotonic() - t0
    print(f"every process of the session ended in {took:.1f} s (aim: {ENDED_WITHIN_S:g} s)")
    return took


def assert_log_whole(cwd: Path, session_id: str) -> None:
    """The event log reads to its end (no record cut short) and replays; the live recording
    was written."""
    run = cwd / "runs" / session_id
    log = read_events(run / "events.msgpack")
    assert log.records and log.incomplete_tail == 0, log.describe_tail()
    assert (run / "recording.rrd").stat().st_size > 0
    replay = subprocess.run(
        [VOXSHAPE, "replay", str(run), "--output", str(cwd / "again.rrd")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert replay.returncode == 0, replay.stderr
    assert not (run / RECORD_FILE).exists() or not SessionRecord.read(run / RECORD_FILE).alive()


def close_its_terminal(up: subprocess.Popen) -> None:
    up.stdout.close()  # the terminal is gone: the launcher's output goes nowhere
    os.killpg(up.pid, signal.SIGHUP)  # and its process group is hung up


def press_ctrl_c_twice(up: subprocess.Popen) -> None:
    os.killpg(up.pid, signal.SIGINT)  # a terminal's Ctrl-C reaches the launcher's group
    read_until(up, r"(took|stopped) |left the bus", timeout=30)  # it is stopping
    os.killpg(up.pid, signal.SIGINT)
    read_until(up, r"at once", timeout=30)


def kill_the_launcher_alone(up: subprocess.Popen) -> None:
    up.kill()  # its services are in sessions of their own: nothing reaches them


@pytest.mark.long
@SESSIONS
@pytest.mark.parametrize("end", [close_its_terminal, press_ctrl_c_twice, kill_the_launcher_alone])
def test_its_services_end_with_the_launcher(spawn, ended, tmp_path, end):
    up, _, _ = start_session(spawn, ended, tmp_path)
    end(up)
    wait_ended(ended)
    up.wait(30)
    assert_log_whole(tmp_path, ended)


@pytest.mark.long
@SESSIONS
def test_sigterm_ends_the_session_and_status_names_it_before(spawn, ended, tmp_path):
    session_id = ended
    up, port, _ = start_session(spawn, session_id, tmp_path)
    status = subprocess.run(  # the default session is not there: this one is named
        [VOXSHAPE, "status", "--connect", f"tcp/127.0.0.1:{port}"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
        env={k: v for k, v in os.environ.items() if not k.startswith("VOXSHAPE_")},
    )
    assert status.returncode == 0, status.stderr
    assert f"session {session_id!r}" in status.stdout, status.stdout
    assert f"kill {up.pid}" in status.stdout, status.stdout
    second = subprocess.run(
        [VOXSHAPE, "up", "--port", str(port), "--session", f"{session_id}b"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )
    assert second.returncode == 2 and f"kill {up.pid}" in second.stderr, second.stderr
    up.send_signal(signal.SIGTERM)
    wait_ended(session_id)
    out, _ = up.communicate(timeout=30)
    assert "stopped" in out
    assert "\x1b[" not in out and "write_footer" not in out  # rerun's warning is left out
    assert_log_whole(tmp_path, session_id)


ORPHAN = """
import signal, sys, time
from voxshape.runtime.processes import end_with_parent
if sys.argv[1] == "deaf":
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
end_with_parent()
time.sleep(60)
"""


@pytest.mark.parametrize(("kind", "ended_by"), [("stops", -signal.SIGTERM), ("deaf", -9)])
def test_a_child_whose_parent_is_gone_is_ended_by_the_watch(spawn, kind, ended_by):
    """The fallback of the kernel's parent-death signal (a parent gone before the child set
    it; not Linux): the parent's pid watched. A child deaf to SIGTERM is killed after the
    grace."""
    env = {**os.environ, PARENT_VARIABLE: "1"}  # a parent that is not its own: gone already
    child = spawn([sys.executable, "-c", ORPHAN, kind], env=env)
    assert child.wait(ORPHAN_GRACE_S + 30) == ended_by


def test_a_child_started_from_a_thread_outlives_that_thread():
    """The kernel's parent-death signal follows the thread that started a child: a child a
    launcher starts from another thread watches the launcher's pid alone, and lives on when
    that thread ends."""
    children: list[subprocess.Popen] = []

    def start() -> None:  # the thread ends once the child watches
        env = ending_with_me(dict(os.environ))
        said = "\nprint('watching', flush=True)\ntime.sleep(60)"
        script = ORPHAN.replace("\ntime.sleep(60)", said)
        child = subprocess.Popen([sys.executable, "-c", script, "stops"], env=env, stdout=PIPE)
        children.append(child)
        assert child.stdout.readline() == b"watching\n"

    starter = threading.Thread(target=start)
    starter.start()
    starter.join()
    (child,) = children
    try:
        time.sleep(1.0)  # the kernel's signal would come at once
        assert child.poll() is None
    finally:
        child.kill()
        child.wait(10)

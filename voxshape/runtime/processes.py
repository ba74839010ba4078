"""Ending a child process (asked first, killed if it does not listen), and a child ending
with the process that started it, however that one ends.

A launcher starts its services in sessions of their own (Ctrl-C reaches the launcher alone,
which stops them in order), so nothing of the terminal reaches them: a launcher that dies
(SIGKILL, a terminal closed under it) would leave them running. A launcher names itself in
PARENT_VARIABLE; a child that finds it there (`end_with_parent`) is sent SIGTERM, the signal
every node stops cleanly on, when that process is gone: at once by the kernel on Linux
(PR_SET_PDEATHSIG), and by a watch of its parent's pid everywhere (every WATCH_S). One that
has not ended ORPHAN_GRACE_S later is killed.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import MutableMapping

PARENT_VARIABLE = "VOXSHAPE_PARENT_PID"  # the pid of the process a child ends with
WATCH_S = 0.5  # how often a child looks for its parent
ORPHAN_GRACE_S = 4.0  # a child that outlives its parent by this much after SIGTERM is killed
PR_SET_PDEATHSIG = 1  # linux/prctl.h


def end_process(proc: subprocess.Popen, grace_s: float, kill_wait_s: float = 10.0) -> int | None:
    """SIGTERM, then SIGKILL if it has not ended within `grace_s`; its exit code, or None
    when it had to be killed."""
    if proc.poll() is None:
        proc.terminate()
    try:
        return proc.wait(grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(kill_wait_s)
        return None


def ending_with_me(environment: MutableMapping[str, str]) -> MutableMapping[str, str]:
    """`environment` for a child that is to end with this process. The kernel's signal comes
    when the thread that started the child ends, not its process: a child started from
    another thread than the main one is told to watch the pid alone (`<pid>:watch`)."""
    main = threading.current_thread() is threading.main_thread()
    environment[PARENT_VARIABLE] = f"{os.getpid()}{'' if main else ':watch'}"
    return environment


def end_with_parent(environ: MutableMapping[str, str] = os.environ) -> int | None:
    """When PARENT_VARIABLE names this process's parent: SIGTERM to this process once that
    parent is gone, SIGKILL ORPHAN_GRACE_S later. The variable is taken out (this process's
    own children are not its parent's). The parent's pid, or None when none was named."""
    named, _, how = (environ.pop(PARENT_VARIABLE, None) or "").partition(":")
    if not named.isdigit():
        return None
    parent = int(named)
    if sys.platform.startswith("linux") and how != "watch":
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    watch = threading.Thread(target=_watch, args=(parent,), name="parent-watch", daemon=True)
    watch.start()  # it also covers a parent gone before the prctl
    return parent


def _watch(parent: int) -> None:
    """Waits for `parent` to be gone (this process adopted by another), then ends this one."""
    while os.getppid() == parent:
        time.sleep(WATCH_S)
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(ORPHAN_GRACE_S)
    os.kill(os.getpid(), signal.SIGKILL)

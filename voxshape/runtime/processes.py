"""Ending a child process: asked first, killed if it does not listen."""

from __future__ import annotations

import subprocess


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

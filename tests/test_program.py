"""`voxshape` as a program ends without finalizing the interpreter, so that zenoh's native
threads cannot abort a process whose work is done ("FATAL: exception not rethrown"), and
still does what finalization would: joins its threads, runs atexit's functions, flushes."""

from __future__ import annotations

import subprocess
import sys
import textwrap

PROGRAM = textwrap.dedent(
    """
    import atexit, sys, threading, time
    from voxshape import cli

    class Finalized:
        def __del__(self):
            print("finalized", flush=True)

    kept = Finalized()  # a module global: only the interpreter's finalization deletes it

    def main():
        threading.Thread(target=lambda: (time.sleep(0.3), print("thread ended"))).start()
        atexit.register(print, "atexit ran")
        print("unflushed", end="")
        return int(sys.argv[1])

    cli.main = main
    cli.program()
    """
)


def run(*args: str) -> subprocess.CompletedProcess:
    command = [sys.executable, "-c", PROGRAM, *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=60)


def test_the_program_exits_with_mains_code_after_its_threads_and_atexit_without_finalizing():
    result = run("3")
    assert result.returncode == 3, result.stderr
    assert result.stdout.split("\n") == ["unflushedthread ended", "atexit ran", ""]
    assert "finalized" not in result.stdout


def test_a_usage_error_keeps_its_exit_code():
    result = subprocess.run(
        [sys.executable, "-m", "voxshape", "no-such-command"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2 and "invalid choice: 'no-such-command'" in result.stderr

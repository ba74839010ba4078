"""What a new user does that must break nothing (issue 55), each against real processes: a word
said before the robot's first step and to a robot that is not there, a second session of the
same name, the recording process killed, `voxshape demo --resume`, an experiment run twice.
Each ends with no traceback, the run folder intact, and `voxshape replay` rendering it; every
refusal exits non-zero."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import time
from pathlib import Path

import pexpect
import pytest

from tests.conftest import VOXSHAPE, free_port
from tests.logger_support import rows


def session_env(session: str, port: int) -> dict[str, str]:
    router = f"tcp/127.0.0.1:{port}"
    return {
        **os.environ,
        "VOXSHAPE_SESSION": session,
        "VOXSHAPE_ROUTER": router,  # where `voxshape up`'s services connect
        "VOXSHAPE_ROUTER_LISTEN": router,
        "VOXSHAPE_CONNECT": router,  # where `voxshape teach` connects
        "VOXSHAPE_VIEWER_PORT": str(free_port()),
        "TERM": "dumb",
    }


def start(argv: list[str], cwd: Path, env: dict[str, str], timeout: float = 120):
    return pexpect.spawn(VOXSHAPE, argv, cwd=str(cwd), env=env, encoding="utf-8", timeout=timeout)


def stop(child: pexpect.spawn, timeout: float = 30.0) -> str:
    """Ctrl-C, as a user does; what it printed until it ended."""
    child.sendintr()
    child.expect(pexpect.EOF, timeout=timeout)
    child.close()
    return child.before


def teach(words: list[str], robot: str, cwd: Path, env: dict[str, str]) -> tuple[int, str]:
    """`voxshape teach --robot ROBOT` typing `words`; its exit code and what it printed."""
    done = subprocess.run(
        [VOXSHAPE, "teach", "--teacher", "ana", "--robot", robot, "--linger", "2"],
        input="".join(f"{w}\n" for w in words),
        cwd=cwd, env=env, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    return done.returncode, done.stdout + done.stderr


def replays(run: Path) -> Path:
    """`voxshape replay RUN`: exit 0, no traceback; the replay's recording."""
    done = subprocess.run(
        [VOXSHAPE, "replay", str(run)], capture_output=True, text=True, timeout=180
    )
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr[-3000:]
    return run / "replay.rrd"


def descendants(pid: int) -> list[int]:
    """The processes under `pid` (it started them), nearest first."""
    found, queue = [], [pid]
    while queue:
        parent = queue.pop(0)
        for task in Path(f"/proc/{parent}/task").glob("*/children"):
            children = [int(c) for c in task.read_text().split()]
            found += children
            queue += children
    return found


def command_of(pid: int) -> str:
    return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()


@pytest.mark.timeout(300)
@pytest.mark.long
def test_words_before_the_first_step_and_to_no_robot_are_recorded(tmp_path, session_id):
    """No simulator: robot r1 never steps, r9 does not exist. The words are recorded, the
    recording process lives on, teach says the robot never appeared and exits 1, and the
    run replays with every word in it."""
    env = session_env(session_id, free_port())
    up = start(["up", "--no-sim"], tmp_path, env)
    try:
        up.expect(r"ready in [\d.]+ s")
        code_r1, said_r1 = teach(["good", "left"], "r1", tmp_path, env)
        code_r9, said_r9 = teach(["bad"], "r9", tmp_path, env)
        time.sleep(1.0)  # the recording draws them
    finally:
        printed = stop(up)
    assert up.exitstatus == 0 and "Traceback" not in printed, printed[-3000:]
    assert "recording process died" not in printed, printed[-3000:]
    assert code_r1 == 1 and "robot 'r1' never appeared" in said_r1, said_r1
    assert code_r9 == 1 and "robot 'r9' is not running" in said_r9, said_r9
    run = tmp_path / "runs" / session_id
    assert {"events.msgpack", "session.json", "recording.rrd"} <= {p.name for p in run.iterdir()}
    texts = [r[-1][0] for r in rows(replays(run))["/log/teachers/ana"]]
    for robot, word in (("r1", "good"), ("r1", "left"), ("r9", "bad")):
        assert any(f"ana to {robot}: '{word}'" in t for t in texts), texts


@pytest.mark.timeout(300)
@pytest.mark.long
def test_a_second_session_of_the_same_name_is_refused_and_moves_nothing(tmp_path, session_id):
    """As the port-in-use hint leads: a second `voxshape up --port` of the same session is
    refused in one line naming the folder and the way out; the first goes on, its folder in
    place. Its recording process killed, the event log goes on and replays whole."""
    env = session_env(session_id, free_port())
    run = tmp_path / "runs" / session_id
    up = start(["up", "--rtf", "5"], tmp_path, env)
    try:
        up.expect(r"ready in [\d.]+ s")
        again = start(["up", "--port", str(free_port())], tmp_path, env)
        again.expect(pexpect.EOF)
        again.close()
        refusal = again.before.strip().splitlines()
        renderer = next(p for p in descendants(up.pid) if "replay" in command_of(p))
        os.kill(renderer, signal.SIGKILL)  # the recording process dies mid-session
        up.expect("the recording process died; the event log goes on", timeout=30)
        time.sleep(2.0)  # the session goes on, logged
    finally:
        printed = stop(up)
    assert again.exitstatus == 2, refusal
    assert (
        len(refusal) == 1
        and f"runs/{session_id} belongs to a session that is running" in (refusal[0])
    ), refusal
    assert "--session NAME" in refusal[0]
    assert up.exitstatus == 0 and "Traceback" not in printed, printed[-3000:]
    assert [p.name for p in run.parent.iterdir()] == [session_id]  # nothing moved aside
    steps = rows(replays(run)).get("/world/map/poses/r1", [])
    assert len(steps) > 50, len(steps)  # before and after the recorder died


@pytest.mark.timeout(400)
@pytest.mark.long
def test_demo_resume_goes_on_with_the_latest_demo(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "VOXSHAPE_SESSION"}
    env["VOXSHAPE_ROUTER"] = env["VOXSHAPE_ROUTER_LISTEN"] = f"tcp/127.0.0.1:{free_port()}"
    argv = [VOXSHAPE, "demo", "--speech", "mock", "--rtf", "20", "--max-episodes", "3"]
    first = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=180)
    assert first.returncode in (0, 1), first.stdout[-3000:]  # converged, or gave up at 3
    (demo,) = (tmp_path / "runs").iterdir()
    second = subprocess.run(
        [*argv, "--resume"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=180
    )
    assert second.returncode in (0, 1), second.stdout[-3000:]
    said = second.stdout + second.stderr
    assert re.search(rf"resuming the run in runs/{demo.name}: learner r1 at episode [1-9]", said)
    assert [p.name for p in (tmp_path / "runs").iterdir()] == [demo.name]
    assert "Traceback" not in said
    episodes = rows(replays(demo)).get("/episode/return/r1", [])
    assert len(episodes) >= 6  # both runs' in one event log


@pytest.mark.timeout(300)
@pytest.mark.long
def test_an_experiment_never_overwrites_earlier_results(tmp_path):
    argv = [VOXSHAPE, "experiment", "paper", "--tasks", "1", "--seeds", "1",
            "--max-episodes", "1", "--workers", "1", "--no-progress"]  # fmt: skip
    out = tmp_path / "runs" / "experiment-paper"
    first = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=240)
    assert first.returncode == 0, first.stderr[-3000:]
    written = (out / "results.json").read_text()
    second = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=240)
    assert second.returncode == 0, second.stderr[-3000:]
    (kept,) = (p for p in out.parent.iterdir() if p != out)
    assert f"runs/experiment-paper held earlier results: kept as runs/{kept.name}" in (
        second.stderr
    )
    assert (kept / "results.json").read_text() == written and (out / "results.json").exists()

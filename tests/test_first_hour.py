"""A new user's first hour, walked in pseudo terminals (pexpect) as the README tells it: a
session by hand (`voxshape up`, `voxshape teach --teacher ana --robot r1`, `voxshape status`),
typed words that reach the learner, a second `voxshape up` that starts a new run, a wrong
password, the Gymnasium line and the demo on a map file of one's own.

Only the router's port and the session's name differ from the README: they come from the
environment (VOXSHAPE_ROUTER, VOXSHAPE_CONNECT, VOXSHAPE_SESSION), so the commands are typed as
written and the test never meets another session on port 7447.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pexpect
import pytest

from tests.conftest import ROOT, VOXSHAPE, free_port, seconds_to_start
from voxshape.launcher import router_command

README = (ROOT / "README.md").read_text()
MAPS = ROOT / "tests" / "fixtures" / "maps"


def session_env(session: str, port: int) -> dict[str, str]:
    router = f"tcp/127.0.0.1:{port}"
    return {
        **os.environ,
        "VOXSHAPE_SESSION": session,
        "VOXSHAPE_ROUTER": router,  # where `voxshape up`'s services connect
        "VOXSHAPE_ROUTER_LISTEN": router,
        "VOXSHAPE_CONNECT": router,  # where `voxshape teach` and `status` connect
        "VOXSHAPE_VIEWER_PORT": str(free_port()),  # the logger's live recording
        "TERM": "dumb",
    }


def run_as_written(command: str, cwd: Path, env: dict[str, str], timeout: float) -> pexpect.spawn:
    """A README command in a pseudo terminal, `voxshape` being this installation's."""
    assert command in README, f"not in the README: {command}"
    program, *args = command.split()
    executable = VOXSHAPE if program == "voxshape" else program
    return pexpect.spawn(executable, args, cwd=str(cwd), env=env, encoding="utf-8", timeout=timeout)


def stop(child: pexpect.spawn, timeout: float = 30.0) -> str:
    """Ctrl-C, as a user does; what it printed until it ended."""
    child.sendintr()
    try:
        child.expect(pexpect.EOF, timeout=timeout)
    except pexpect.TIMEOUT:
        pytest.fail(f"not stopped {timeout:g} s after Ctrl-C; its output:\n{child.before[-4000:]}")
    child.close()
    return child.before


def checkpoint_meta(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as data:
        return json.loads(str(data["meta"]))


@pytest.mark.timeout(400)
@pytest.mark.long
def test_the_first_hour_of_a_new_user(tmp_path, session_id):
    env = session_env(session_id, free_port())
    run_dir = tmp_path / "runs" / session_id

    # terminal 1: the session; terminal 2: a teacher typing good, bad, left
    up = run_as_written("voxshape up", tmp_path, env, timeout=120)
    try:
        up.expect(r"ready in [\d.]+ s")
        up.expect("voxshape teach")  # it says what to run next
        teach = run_as_written("voxshape teach --teacher ana --robot r1", tmp_path, env, 30)
        teach.expect("say> ")
        for word, answer in (
            ("good", "understood 'good'"),
            ("bad", "understood 'bad'"),
            ("left", "understood 'left': command left"),
        ):
            teach.sendline(word)
            teach.expect(re.escape(answer))
        teach.sendeof()
        # a Ctrl-D typed while the client redraws between two prompts can be lost: type it again
        if teach.expect([pexpect.EOF, pexpect.TIMEOUT], timeout=10) == 1:
            teach.sendeof()
            teach.expect(pexpect.EOF)
        teach.close()
        assert teach.exitstatus == 0

        status = run_as_written("voxshape status", tmp_path, env, timeout=30)
        status.expect(pexpect.EOF)
        status.close()
        for service in ("sim", "learner", "arbiter", "speech", "logger"):
            assert service in status.before, status.before
    finally:
        stopped = stop(up)
    assert up.exitstatus == 0, stopped[-3000:]
    # the learner took all three: its checkpoint (written on stopping) names them
    first = checkpoint_meta(run_dir / "learner-r1.npz")
    assert len(first["feedback_taken"]) == 3, first

    # a second `voxshape up` of the session: the first run is kept aside, the learner fresh
    up = run_as_written("voxshape up", tmp_path, env, timeout=120)
    try:
        up.expect(r"kept as (runs/\S+?)[;:,]?\s")
        kept = tmp_path / up.match.group(1)
        up.expect(r"ready in [\d.]+ s")
    finally:
        stop(up)
    assert kept != run_dir and (kept / "events.msgpack").exists()
    assert checkpoint_meta(kept / "learner-r1.npz")["feedback_taken"] == first["feedback_taken"]
    assert checkpoint_meta(run_dir / "learner-r1.npz")["feedback_taken"] == []


def test_a_wrong_password_is_told_within_2_s(tmp_path, session_id):
    """A secured router as `voxshape certs` and `voxshape router --secrets` make it; ana types
    a wrong password: one line naming her and the router, within 2 s of the client's start."""
    secrets = tmp_path / "secrets"
    subprocess.run([VOXSHAPE, "certs", str(secrets)], check=True, capture_output=True)
    port = free_port()
    env = session_env(session_id, port)
    router_env = {k: v for k, v in env.items() if k != "VOXSHAPE_CONNECT"}
    access = str(ROOT / "deploy" / "access.toml")
    voxshape, *argv = router_command("--secrets", str(secrets), "--access", access)
    router = pexpect.spawn(
        voxshape,
        argv,
        env={**router_env, "VOXSHAPE_LISTEN": env["VOXSHAPE_CONNECT"]},
        encoding="utf-8",
        timeout=30,
    )
    beyond_start = []  # the best of 3: a loaded machine only ever adds to a time
    try:
        router.expect("joined the bus")
        for _ in range(3):
            python_start = seconds_to_start(env)
            teach = pexpect.spawn(
                VOXSHAPE,
                ["teach", "--user", "ana"],
                env={**env, "VOXSHAPE_PASSWORD": "not-her-password"},
                encoding="utf-8",
                timeout=15,
            )
            started = time.monotonic()
            teach.expect(pexpect.EOF)
            beyond_start.append(time.monotonic() - started - python_start)
            teach.close()
            lines = [line for line in teach.before.splitlines() if line.strip()]
            assert len(lines) == 1 and "refused user 'ana'" in lines[0], teach.before
            assert teach.exitstatus != 0
            if beyond_start[-1] < 2.0:
                break
    finally:
        stop(router)
    assert min(beyond_start) < 2.0, beyond_start


@pytest.mark.timeout(300)
def test_a_remote_teacher_joins_a_secured_session_as_the_readme_says(tmp_path, session_id):
    """The README's remote-teacher line, as written but for the router's address: a session
    secured with `voxshape certs` and a TLS listener (docs/deployment.md), the teacher given
    the CA and asked for her password, and her typed "good" understood."""
    secrets = tmp_path / "secrets"
    subprocess.run([VOXSHAPE, "certs", str(secrets)], check=True, capture_output=True)
    shutil.copy(secrets / "ca.pem", tmp_path / "ca.pem")  # what the admin hands out
    (password,) = [
        line.split(":", 1)[1] for line in (secrets / "credentials").read_text().splitlines()
        if line.startswith("ana:")
    ]  # fmt: skip
    tcp, tls = free_port(), free_port()
    env = session_env(session_id, tcp)
    up_env = {
        **env,
        "VOXSHAPE_SECRETS": str(secrets),
        "VOXSHAPE_ROUTER_LISTEN": f"tcp/127.0.0.1:{tcp},tls/127.0.0.1:{tls}",
    }
    teacher_env = {k: v for k, v in env.items() if k != "VOXSHAPE_CONNECT"}  # another machine
    written = "voxshape teach --connect tls/lab.example:7448 --tls-root-ca ca.pem --user ana"
    written += " --teacher ana"
    assert written in " ".join(README.split())
    _, *args = written.replace("lab.example:7448", f"localhost:{tls}").split()
    up = pexpect.spawn(
        VOXSHAPE, ["up"], cwd=str(tmp_path), env=up_env, encoding="utf-8", timeout=120
    )
    try:
        up.expect(r"ready in [\d.]+ s")
        teach = pexpect.spawn(
            VOXSHAPE, args, cwd=str(tmp_path), env=teacher_env, encoding="utf-8", timeout=60
        )
        teach.expect("password for ana: ")
        teach.sendline(password)
        teach.expect("say> ")
        teach.sendline("good")
        teach.expect(re.escape("understood 'good'"))
        teach.sendeof()
        teach.expect(pexpect.EOF)
        teach.close()
        assert teach.exitstatus == 0
    finally:
        stopped = stop(up)
    assert up.exitstatus == 0, stopped[-3000:]


@pytest.mark.timeout(300)
@pytest.mark.long
def test_the_demo_on_a_map_file_converges_and_says_so(tmp_path, session_id):
    shutil.copy(MAPS / "long-room.toml", tmp_path / "mine.toml")
    env = session_env(session_id, free_port())
    demo = pexpect.spawn(
        VOXSHAPE,
        ["demo", "--task", "mine.toml", "--speech", "mock", "--rtf", "20"],
        cwd=str(tmp_path),
        env=env,
        encoding="utf-8",
        timeout=240,
    )
    demo.expect(r"The robot learnt map mine.toml \(.*\) in (\d+) episodes")
    demo.expect(pexpect.EOF)
    demo.close()
    assert demo.exitstatus == 0, demo.before[-3000:]
    assert "mine.toml" in (tmp_path / "runs" / session_id / "demo.md").read_text()

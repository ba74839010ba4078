"""A person's command given a port of this host where nothing listens says so at once (the
kernel refuses the connection: no wait can change it) instead of waiting its 10 s connect
timeout, and its hint names the flag that sets that port in that very command (`voxshape
ros2`'s session is --bus; its --connect is the robot's). Given --connect-timeout, it waits:
a router may be starting."""

from __future__ import annotations

import os
import subprocess

import pytest

from tests.conftest import VOXSHAPE, free_port

AT = "tcp/127.0.0.1:{port}"
# argv after `voxshape`, with {port} the refusing port; the flag that sets it there
COMMANDS = {
    "teach": (["teach", "--connect", AT], "--connect"),
    "status": (["status", "--connect", AT], "--connect"),
    "ros2": (["ros2", "--bus", AT, "--connect", AT, "--goal", "2,0"], "--bus"),
}


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_refused_local_port_fails_at_once_naming_the_flag_of_the_command(command):
    argv, flag = COMMANDS[command]
    port = free_port()  # nothing listens there
    env = {k: v for k, v in os.environ.items() if not k.startswith("VOXSHAPE_")}
    done = subprocess.run(
        [VOXSHAPE, *(a.format(port=port) for a in argv)],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
        stdin=subprocess.DEVNULL,
    )
    assert done.returncode == 2, done.stdout + done.stderr
    assert f"nothing listens at tcp/127.0.0.1:{port} (refused at once)" in done.stderr
    assert f"check {flag}/VOXSHAPE_CONNECT" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr


def test_a_connect_timeout_given_is_waited_for():
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("VOXSHAPE_")}
    argv = [VOXSHAPE, "status", "--connect", f"tcp/127.0.0.1:{port}", "--connect-timeout", "1"]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=120, env=env)
    assert done.returncode == 2 and f"cannot reach tcp/127.0.0.1:{port} within 1 s" in done.stderr

"""Three hosts, made of network namespaces joined by veth pairs (the test creates them; it
needs root, as in CI): the secured router in one, simulator + learner + arbiter in a second,
a teacher in a third, reaching the router over TLS. A typed "good" becomes credited feedback
on the robot's feedback key, which the learner subscribes to.

    services 10.77.1.2 ---- 10.77.1.1 router 10.77.2.1 ---- 10.77.2.2 teacher
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.conftest import ROOT, VOXSHAPE, read_until
from voxshape.deploy.access import find_access_file, load_access
from voxshape.deploy.certs import make_all
from voxshape.launcher import router_command

ROUTER_TO_SERVICES, SERVICES = "10.77.1.1", "10.77.1.2"
ROUTER_TO_TEACHER, TEACHER = "10.77.2.1", "10.77.2.2"


def ip(*argv: str) -> None:
    subprocess.run(["ip", *argv], check=True, capture_output=True, text=True, timeout=30)


def namespaces_unavailable() -> str | None:
    """Why namespaces cannot be made here, or None."""
    if shutil.which("ip") is None:
        return "the ip command is missing (Debian package iproute2)"
    if os.geteuid() != 0:
        return "creating network namespaces needs root (CI runs as root)"
    probe = f"vxp{uuid.uuid4().hex[:6]}"
    try:
        ip("netns", "add", probe)
    except subprocess.CalledProcessError as e:
        return f"cannot create a network namespace here: {e.stderr.strip()}"
    ip("netns", "del", probe)
    return None


@pytest.fixture
def hosts() -> Iterator[dict[str, str]]:
    why = namespaces_unavailable()
    if why:
        pytest.skip(why)
    tag = uuid.uuid4().hex[:6]
    names = {role: f"vx{role[0]}{tag}" for role in ("router", "services", "teacher")}
    try:
        for name in names.values():
            ip("netns", "add", name)
            ip("-n", name, "link", "set", "lo", "up")
        for peer, here, there in (
            ("services", ROUTER_TO_SERVICES, SERVICES),
            ("teacher", ROUTER_TO_TEACHER, TEACHER),
        ):
            near, far = f"vr{peer[0]}{tag}", f"v{peer[0]}{tag}"  # at most 15 characters
            ip("link", "add", near, "netns", names["router"], "type", "veth", "peer", "name", far)
            ip("link", "set", far, "netns", names[peer])
            ip("-n", names["router"], "addr", "add", f"{here}/24", "dev", near)
            ip("-n", names[peer], "addr", "add", f"{there}/24", "dev", far)
            ip("-n", names["router"], "link", "set", near, "up")
            ip("-n", names[peer], "link", "set", far, "up")
        yield names
    finally:
        for name in names.values():  # deleting a namespace deletes its veth ends
            subprocess.run(["ip", "netns", "del", name], capture_output=True, timeout=30)


def in_host(host: str, *argv: str) -> list[str]:
    return ["ip", "netns", "exec", host, *argv]


def wait_seen_from_the_teacher(hosts: dict, teacher_bus: tuple, env: dict) -> None:
    """Until the teacher's host sees the robot's services through the router (90 s at most)."""
    deadline = time.monotonic() + 90
    while True:
        status = subprocess.run(
            in_host(
                hosts["teacher"],
                *(VOXSHAPE, "status", *teacher_bus, "--require", "sim", "learner", "arbiter"),
            ),
            capture_output=True,
            text=True,
            timeout=60,
            env=env,
        )
        if status.returncode == 0:
            return
        assert time.monotonic() < deadline, status.stdout + status.stderr
        time.sleep(1.0)


def test_a_typed_good_crosses_three_hosts_to_the_learner(hosts, spawn, session_id, tmp_path):
    secrets = tmp_path / "secrets"
    make_all(secrets, load_access(find_access_file(ROOT)), hosts=[ROUTER_TO_TEACHER])
    env = {**os.environ, "VOXSHAPE_SESSION": session_id, "VOXSHAPE_SECRETS": str(secrets)}
    for name in ("VOXSHAPE_USER", "VOXSHAPE_PASSWORD", "VOXSHAPE_CONNECT", "VOXSHAPE_MODE"):
        env.pop(name, None)
    router = spawn(
        in_host(
            hosts["router"],
            *router_command("--node", "router", "--listen", "tcp/0.0.0.0:7447,tls/0.0.0.0:7448"),
        ),
        env=env,
        text=True,
        stderr=subprocess.STDOUT,
        cwd=tmp_path,
    )
    read_until(router, r"secured:", timeout=60)
    client = ("--mode", "client", "--connect", f"tcp/{ROUTER_TO_SERVICES}:7447")
    for service in (("sim", "--task", "1"), ("learner",), ("arbiter",)):
        spawn(
            in_host(hosts["services"], VOXSHAPE, *service, "--node", service[0], *client),
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            cwd=tmp_path,  # the learner keeps its checkpoint under ./runs
        )
    teacher_bus = (
        *("--mode", "client", "--connect", f"tls/{ROUTER_TO_TEACHER}:7448"),
        *("--user", "ana"),
    )
    wait_seen_from_the_teacher(hosts, teacher_bus, env)
    teach = subprocess.run(
        in_host(
            hosts["teacher"],
            *(VOXSHAPE, "teach", *teacher_bus, "--teacher", "ana", "--robot", "r1"),
            *("--json", "--linger", "4"),
        ),
        input="good\n",
        capture_output=True,
        text=True,
        timeout=90,
        env=env,
    )
    events = [json.loads(line) for line in teach.stdout.splitlines() if line.startswith("{")]
    credited = [e for e in events if e["event"] == "feedback" and "ana" in e["teachers"]]
    assert credited, teach.stdout + teach.stderr
    assert credited[0]["kind"] == "reward" and credited[0]["reward"] > 0 and credited[0]["steps"]
    print(f"credited across three hosts: {credited[0]}")


def test_secrets_name_the_teachers_router_address(tmp_path):
    """The router's certificate names the address remote teachers use (TLS checks it)."""
    make_all(tmp_path, ["ana"], hosts=[ROUTER_TO_TEACHER, "lab.example"])
    text = subprocess.run(
        [
            "openssl",
            "x509",
            "-in",
            str(tmp_path / "router.pem"),
            "-noout",
            "-ext",
            "subjectAltName",
        ],
        capture_output=True,
        text=True,
        timeout=30,
    ).stdout
    for name in (f"IP Address:{ROUTER_TO_TEACHER}", "DNS:lab.example", "DNS:router", "localhost"):
        assert name in text, text
    assert (tmp_path / "credentials").stat().st_mode & 0o077 == 0
    assert Path(tmp_path / "ana.key").stat().st_mode & 0o077 == 0

"""One truth for who may teach: `voxshape web` takes its teachers from the access file its
router enforces. The router says which (path and SHA-256, to any user); the page compares at
start and stops with an error naming both files when they differ, or when its router is open;
a router that does not answer (not voxshape's) gets a warning, never a silent pass. compose and
`voxshape up` give both the same VOXSHAPE_ACCESS."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import yaml

from tests.conftest import ROOT, VOXSHAPE, free_port, read_until, wait_for_port
from voxshape.deploy.access import compare_with_router
from voxshape.launcher.topology import load_topology, local_variables
from voxshape.protocol import ProtocolError
from voxshape.protocol.queries import AccessAnswer

DIGEST = "ab" * 32


def answer(zid: str = "a1", sha256: str | None = DIGEST) -> AccessAnswer:
    path = None if sha256 is None else "/access.toml"
    return AccessAnswer("router", zid, path, sha256)


def test_an_answer_travels_as_json_and_anything_else_is_refused():
    assert AccessAnswer.from_bytes(answer().to_bytes()) == answer()
    assert AccessAnswer.from_bytes(answer(sha256=None).to_bytes()).open
    good = json.loads(answer().to_bytes())
    for bad in (
        b"not json",
        b"[]",
        json.dumps({**good, "extra": 1}).encode(),
        json.dumps({**good, "sha256": "AB" * 32}).encode(),
        json.dumps({**good, "path": None}).encode(),  # a digest of no file
        json.dumps({**good, "zid": "not hex"}).encode(),
        b"{" * 5000,
    ):
        with pytest.raises(ProtocolError):
            AccessAnswer.from_bytes(bad)


def test_the_page_compares_its_access_file_with_its_own_routers():
    mine = Path("/lab/access.toml")
    assert compare_with_router(mine, DIGEST, [answer()], {"a1"}) == (None, None)
    error, _ = compare_with_router(mine, "cd" * 32, [answer()], {"a1"})
    assert "/access.toml" in error and "/lab/access.toml" in error
    assert "the same --access (VOXSHAPE_ACCESS)" in error
    error, _ = compare_with_router(mine, DIGEST, [answer(sha256=None)], {"a1"})
    assert "is open" in error
    # Two sites mesh: only its own router's answer counts.
    other = AccessAnswer("router-b", "b2", "/elsewhere.toml", "ef" * 32)
    assert compare_with_router(mine, DIGEST, [answer(), other], {"a1"}) == (None, None)
    for answers in ([], [other]):  # no answer from its router: said, not passed silently
        error, warning = compare_with_router(mine, DIGEST, answers, {"a1"})
        assert error is None and "did not say which access file" in warning
        assert "/lab/access.toml" in warning


def web(secured: tuple[str, Path]) -> list[str]:
    """`voxshape web` as the `web` user of the secured kit (a later --connect wins)."""
    endpoint, secrets = secured
    return [
        *(VOXSHAPE, "web", "--session", "secured", "--mode", "client", "--connect", endpoint),
        *("--node", "web", "--secrets", str(secrets), "--port", str(free_port())),
    ]


def start_failing(argv: list[str], env: dict[str, str], cwd: Path = ROOT) -> str:
    """Runs `voxshape web` that must stop at start; its stderr."""
    try:
        done = subprocess.run(
            argv, capture_output=True, text=True, timeout=60, env={**os.environ, **env}, cwd=cwd
        )
    except subprocess.TimeoutExpired as e:
        pytest.fail(f"still running after 60 s: {e.stderr}")
    assert done.returncode == 2, (done.returncode, done.stderr)
    assert "Traceback" not in done.stderr, done.stderr
    return done.stderr


def test_the_page_refuses_to_start_on_another_access_file_than_its_routers(
    secured, spawn, tmp_path
):
    _, secrets = secured
    env = {"VOXSHAPE_ACCESS": ""}
    # Without --access it would take the project's deploy/access.toml: not the router's.
    err = start_failing(web(secured), env)
    router_file = str((secrets / "access.toml").resolve())
    assert router_file in err and str(ROOT / "deploy" / "access.toml") in err, err
    assert "pass the same --access (VOXSHAPE_ACCESS)" in err, err
    # The same contents under another name: the same teachers, let in.
    copy = tmp_path / "copy.toml"
    shutil.copy(secrets / "access.toml", copy)
    proc = spawn(web(secured), env={**os.environ, "VOXSHAPE_ACCESS": str(copy)}, text=True)
    read_until(proc, "serving the page", stream="stderr")


BARE_ROUTER = """
import json, sys, time, zenoh
conf = zenoh.Config.from_json5(json.dumps({
    "mode": "router",
    "scouting": {"multicast": {"enabled": False}},
    "listen": {"endpoints": [f"tcp/127.0.0.1:{sys.argv[1]}"]},
    "transport": {"auth": {"usrpwd": {"dictionary_file": sys.argv[2]}}},
}))
with zenoh.open(conf):
    time.sleep(120)
"""


def test_a_router_that_does_not_say_is_warned_of_not_passed_silently(secured, spawn, tmp_path):
    """A zenoh router that is not voxshape's (passwords, no answer): the page starts, with a
    warning that names its file and the fix. (A secured page cannot join an open router at
    all: zenoh refuses a password it does not ask for.)"""
    _, secrets = secured
    port, passwords = free_port(), tmp_path / "passwords"
    lines = (secrets / "credentials").read_text().splitlines()
    passwords.write_text("".join(f"{line}\n" for line in lines if line and line[0] != "#"))
    spawn([sys.executable, "-c", textwrap.dedent(BARE_ROUTER), str(port), str(passwords)])
    wait_for_port(port)
    argv = [*web(secured), "--connect", f"tcp/127.0.0.1:{port}"]
    env = {**os.environ, "VOXSHAPE_ACCESS": str(secrets / "access.toml")}
    proc = spawn(argv, env=env, text=True)
    lines = read_until(proc, "serving the page", stream="stderr")
    warning = next(line for line in lines if "did not say which access file" in line)
    assert str(secrets / "access.toml") in warning and "the same --access" in warning


def test_compose_and_the_launcher_give_the_router_and_the_page_one_access_file():
    compose = ROOT / "compose.yaml"
    local = load_topology(compose, local_variables({"VOXSHAPE_ACCESS": "/lab/a.toml"}))
    docker = load_topology(compose, {})
    for services in (local, docker):
        given = {s.name: s.environment.get("VOXSHAPE_ACCESS") for s in services}
        assert given["router"] == given["web"], given
    assert {s.name: s.environment.get("VOXSHAPE_ACCESS") for s in local}["web"] == "/lab/a.toml"
    assert {s.name: s.environment.get("VOXSHAPE_ACCESS") for s in docker}["web"] == "/access.toml"
    # Locally by default both find deploy/access.toml alike (open, or VOXSHAPE_SECRETS set).
    plain = load_topology(compose, local_variables({}))
    assert {s.environment.get("VOXSHAPE_ACCESS") for s in plain if s.name in ("router", "web")} == {
        ""
    }
    # In containers both mount the one host file at /access.toml.
    volumes = {
        n: b.get("volumes", []) for n, b in yaml.safe_load(compose.read_text())["services"].items()
    }
    mount = "${VOXSHAPE_ACCESS:-./deploy/access.toml}:/access.toml:ro"
    assert mount in volumes["router"] and mount in volumes["web"], volumes

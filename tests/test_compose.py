"""compose.yaml: docker-compose accepts it, its hardening is there, and every one of its
services, run locally with its exact command as a client of a secured router (the access file
of deploy/), joins the bus and announces its presence."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml

from tests.conftest import ROOT, VOXSHAPE, free_port, read_until
from voxshape.deploy.access import find_access_file, load_access
from voxshape.deploy.certs import make_all, make_certificate
from voxshape.launcher import router_command
from voxshape.launcher.topology import load_topology, local_variables

COMPOSE = ROOT / "compose.yaml"
PROFILES = ("simteacher", "viewer")


@pytest.mark.skipif(
    shutil.which("docker-compose") is None,
    reason="Debian's docker-compose is missing: `make test` installs it "
    "(deploy/apt-packages-test.txt)",
)
@pytest.mark.parametrize("profiles", [(), PROFILES], ids=["default", "all-profiles"])
def test_docker_compose_accepts_the_file(profiles):
    flags = [f for p in profiles for f in ("--profile", p)]
    result = subprocess.run(
        ["docker-compose", "-f", str(COMPOSE), *flags, "config"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert result.returncode == 0, result.stderr
    services = yaml.safe_load(result.stdout)["services"]
    # docker-compose 1.29 lists the services of every profile in `config`
    assert {"router", "logger", "sim", "learner", "arbiter", "speech", "web", *PROFILES} == set(
        services
    )


def test_the_image_installs_the_programs_the_services_call():
    """No docker engine here to build the image: its Debian packages are checked against
    the programs compose's commands run (espeak-ng and sox for the simulated teacher's audio,
    openssl for certificates) and its Python extras against the engines compose selects."""
    dockerfile = (ROOT / "Dockerfile").read_text()
    installed = set(dockerfile.split("--no-install-recommends", 1)[1].split("\\")[0].split())
    services = yaml.safe_load(COMPOSE.read_text())["services"]
    assert "--audio" in services["simteacher"]["command"]  # heard by the speech service
    assert {"espeak-ng", "sox", "openssl"} <= installed
    engine = services["speech"]["environment"]["VOXSHAPE_SPEECH_ENGINE"]
    # the default engine's second stage is the whisper extra (pocketsphinx, a base dependency)
    assert "cascade" in engine and "pip install '.[whisper]'" in dockerfile


def test_every_container_is_hardened():
    services = yaml.safe_load(COMPOSE.read_text())["services"]
    for name, body in services.items():
        assert body["read_only"] is True, name
        assert body["cap_drop"] == ["ALL"], name
        assert "no-new-privileges:true" in body["security_opt"], name
        assert not str(body["user"]).startswith("0"), name
        published = [str(p) for p in body.get("ports", [])]
        assert all(p.startswith("127.0.0.1:") or p == "7448:7448" for p in published), name
        assert "healthcheck" in body or name == "viewer", name
    assert any("/secrets:ro" in v for v in services["router"]["volumes"])


def test_local_session_runs_the_compose_commands_on_loopback():
    local = load_topology(COMPOSE, local_variables({}), PROFILES)
    docker = load_topology(COMPOSE, {}, PROFILES)
    for here, there in zip(local, docker, strict=True):
        assert here.name == there.name
        if here.name != "viewer":  # its bind address is in its command
            assert here.command == there.command
    by_name = {s.name: s for s in local}
    assert by_name["router"].environment["VOXSHAPE_LISTEN"] == "tcp/127.0.0.1:7447"
    docker_router = next(s for s in docker if s.name == "router")
    assert docker_router.environment["VOXSHAPE_LISTEN"] == "tcp/0.0.0.0:7447,tls/0.0.0.0:7448"
    # Containers are secured; the local session is open unless VOXSHAPE_SECRETS is set.
    assert docker_router.environment["VOXSHAPE_SECRETS"] == "/secrets"
    assert by_name["router"].environment["VOXSHAPE_SECRETS"] == ""
    secured = load_topology(COMPOSE, local_variables({"VOXSHAPE_SECRETS": "/s"}))
    assert {s.environment["VOXSHAPE_SECRETS"] for s in secured} == {"/s"}
    for spec in local:
        if spec.name not in ("router", "viewer"):
            assert spec.environment["VOXSHAPE_MODE"] == "client", spec.name  # never around it
    assert [s.name for s in local if not s.on_bus] == ["viewer"]


@pytest.fixture(scope="module")
def secrets(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("secrets")
    make_all(folder, load_access(find_access_file(ROOT)))
    return folder


def test_each_service_mounts_only_its_own_secrets(secrets, spawn, session_id, tmp_path):
    """No service but the router holds another user's password, none the CA's key; and each
    service's own folder is enough to join (the router, the simulator, a status check)."""
    services = yaml.safe_load(COMPOSE.read_text())["services"]
    users = set(load_access(find_access_file(ROOT)))
    for name, body in services.items():
        mounts = [v.rsplit(":", 2)[0] for v in body.get("volumes", []) if ":/secrets:" in v]
        if name == "viewer":
            assert mounts == [], name
            continue
        (mount,) = mounts
        folder = Path(mount.replace("${VOXSHAPE_SECRETS:-./deploy/secrets}", str(secrets)))
        assert folder.is_dir() and folder.parent.parent == secrets, mount
        assert not list(folder.glob("*ca.key")), name
        holders = {line.split(":", 1)[0] for line in (folder / "credentials").read_text().split()}
        assert holders == (users if name == "router" else {name}), name
    web = secrets / "per-user" / "web"
    assert {p.name for p in web.iterdir()} == {
        *("ca.pem", "credentials", "web.pem", "web.key", "page.pem", "page.key"),
    }
    # The CA signs for the session's names only: a certificate for another site fails.
    ca = (secrets / "ca.pem", secrets / "ca.key")
    other, _ = make_certificate(tmp_path, "other", ca, server_names=["bank.example"])
    verify = ["openssl", "verify", "-CAfile", str(ca[0])]
    assert subprocess.run([*verify, str(other)], capture_output=True, timeout=30).returncode
    assert not subprocess.run([*verify, str(secrets / "page.pem")], timeout=30).returncode
    port = free_port()
    kit = secrets / "per-user"
    bus = ["--session", session_id, "--mode", "client", "--connect", f"tcp/127.0.0.1:{port}"]
    router = ["--node", "router", "--secrets", str(kit / "router")]
    spawn(router_command("--session", session_id, *router, "--listen", bus[-1]))
    spawn([VOXSHAPE, "sim", *bus, "--node", "sim", "--secrets", str(kit / "sim")])
    launcher = ["--secrets", str(kit / "launcher"), "--user", "launcher"]
    for _ in range(30):  # the simulator joins within a few seconds
        status = subprocess.run(
            [VOXSHAPE, "status", *bus, *launcher, "--require", "sim", "--connect-timeout", "30"],
            capture_output=True,
            text=True,
            timeout=60,
        )
        if status.returncode != 1:
            break
        time.sleep(1.0)
    assert status.returncode == 0, status.stdout + status.stderr


def test_every_service_joins_a_secured_router_and_announces_itself(
    spawn, session_id, secrets, tmp_path
):
    """`voxshape up` runs compose's commands; here with the simulated teacher's profile and
    the secrets: each service logs in as its own user with the role deploy/access.toml gives."""
    port = free_port()
    env = {
        **os.environ,
        "VOXSHAPE_SESSION": session_id,
        "VOXSHAPE_SECRETS": str(secrets),
        "VOXSHAPE_WEB_PORT": str(free_port()),
    }
    env.pop("VOXSHAPE_USER", None)
    up = spawn(
        [VOXSHAPE, "up", "--port", str(port), "--profile", "simteacher", "--ready-timeout", "60"],
        env=env,
        text=True,
        stderr=subprocess.STDOUT,
        cwd=tmp_path,
    )
    lines = read_until(up, r"ready in|error", timeout=120)
    assert "ready in" in lines[-1], "\n".join(lines)
    assert any("router     | " in line and "secured:" in line for line in lines), lines
    status = subprocess.run(
        [VOXSHAPE, "status", "--json", "--connect", f"tcp/127.0.0.1:{port}", "--user", "launcher"],
        capture_output=True,
        text=True,
        timeout=30,
        env=env,
    )
    assert status.returncode == 0, status.stderr
    present = {p["node"] for p in json.loads(status.stdout)["present"]}
    expected = {s.node for s in load_topology(COMPOSE, local_variables({}), ("simteacher",))}
    assert expected <= present, (expected, present)
    # Without a password nobody gets in.
    stranger = subprocess.run(
        [VOXSHAPE, "status", "--connect", f"tcp/127.0.0.1:{port}", "--connect-timeout", "2"],
        capture_output=True,
        text=True,
        timeout=30,
        env={k: v for k, v in env.items() if k != "VOXSHAPE_SECRETS"},
    )
    assert stranger.returncode == 2 and "answers but refused this session" in stranger.stderr
    up.send_signal(signal.SIGINT)
    rest, _ = up.communicate(timeout=60)
    assert up.returncode == 0, rest
    stats = json.loads((tmp_path / "runs" / session_id / "logger-stats.json").read_text())
    # The robot ran through the access control: observations out, the learner's actions back.
    assert stats.get("received.obs", 0) > 0 and stats.get("received.action", 0) > 0, stats

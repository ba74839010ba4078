"""Two sites' routers secured from one `voxshape certs` kit: router B logs in to router A over
TLS, each site's access control still holds for its own users, and what cannot mesh is refused
at start (the sites themselves: test_sites.py)."""

from __future__ import annotations

import argparse
import subprocess
import time
from dataclasses import replace
from pathlib import Path

import pytest
import zenoh

from tests.conftest import ROOT, free_port, read_until, wait_for_port
from voxshape.deploy.access import load_access
from voxshape.deploy.certs import make_all
from voxshape.deploy.router import secured
from voxshape.launcher import router_command
from voxshape.launcher.topology import load_topology, local_variables
from voxshape.protocol import robot_key, teacher_key
from voxshape.runtime import ConfigError, bus_config

COMPOSE = ROOT / "compose.yaml"


MESH_ACCESS = """
[users]
logger = { role = "admin" }
sim = { role = "simulator", robots = ["r1"] }
ana = { role = "teacher" }
siteb = { role = "admin" }   # router B's login at router A
"""


def mesh_kit(tmp_path: Path) -> tuple[Path, Path]:
    """The sites' access file and the one kit `voxshape certs` makes from it."""
    access = tmp_path / "access.toml"
    access.write_text(MESH_ACCESS)
    kit = tmp_path / "secrets"
    make_all(kit, load_access(access))
    return access, kit


def login(kit: Path, session_id: str, user: str, port: int) -> zenoh.Session:
    own = {"VOXSHAPE_SECRETS": str(kit / "per-user" / user), "VOXSHAPE_USER": user}
    config = replace(
        bus_config("test", env=own),
        session=session_id,
        mode="client",
        connect=(f"tcp/127.0.0.1:{port}",),
    )
    return zenoh.open(config.zenoh_config())


def test_secured_sites_mesh_over_tls_with_one_kit(tmp_path, spawn, session_id):
    """Router B logs in to router A over TLS as siteb, and each site's access control still
    holds for its own users."""
    access, kit = mesh_kit(tmp_path)
    a_tcp, a_tls, b_tcp = free_port(), free_port(), free_port()
    router = router_command("--session", session_id, "--secrets", str(kit))
    listen_a = f"tcp/127.0.0.1:{a_tcp},tls/127.0.0.1:{a_tls}"
    spawn([*router, "--node", "router-a", "--access", str(access), "--listen", listen_a])
    wait_for_port(a_tcp)
    b = spawn(
        [
            *(*router, "--node", "router-b", "--access", str(access), "--user", "siteb"),
            *("--listen", f"tcp/127.0.0.1:{b_tcp}", "--connect", f"tls/127.0.0.1:{a_tls}"),
        ],
        text=True,
        stderr=subprocess.STDOUT,
    )
    read_until(b, r"node joined role=router node=router-a", timeout=30)
    at_a: list[str] = []
    at_b: list[str] = []
    with (
        login(kit, session_id, "logger", a_tcp) as logger,
        login(kit, session_id, "sim", a_tcp) as sim,
        login(kit, session_id, "ana", b_tcp) as ana,
    ):
        everything = f"voxshape/{session_id}/**"
        logger.declare_subscriber(everything, lambda s: at_a.append(str(s.key_expr)))
        ana.declare_subscriber(robot_key(session_id, "*", "obs"), lambda s: at_b.append("obs"))
        time.sleep(1.5)  # the subscriptions reach the other site
        said = teacher_key(session_id, "ana", "utterance")
        for _ in range(3):
            ana.put(said, b"u")
            ana.put(teacher_key(session_id, "ben", "utterance"), b"not hers")
            ana.put(robot_key(session_id, "r1", "feedback"), b"not a teacher's")
            sim.put(robot_key(session_id, "r1", "obs"), b"o")
            time.sleep(0.1)
        deadline = time.monotonic() + 10
        while (at_a.count(said) < 3 or len(at_b) < 3) and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(0.5)  # anything that should not arrive has had time to
    assert at_a.count(said) == 3 and len(at_b) == 3, (at_a, at_b)
    assert set(at_a) == {said, robot_key(session_id, "r1", "obs")}, at_a  # B's rules held


def test_what_cannot_mesh_is_refused_at_start(tmp_path):
    """Plain TCP between sites, no login there, mutual TLS."""
    access, kit = mesh_kit(tmp_path)
    users = {"VOXSHAPE_SECRETS": str(kit), "VOXSHAPE_ACCESS": str(access)}
    for env, error in (
        ({**users, "VOXSHAPE_CONNECT": "tcp/lab-a.example:7447"}, "tls/ only"),
        ({**users, "VOXSHAPE_CONNECT": "tls/lab-a.example:7448"}, "give --user"),
        (
            {**users, "VOXSHAPE_CONNECT": "tls/a:7448", "VOXSHAPE_USER": "siteb"}
            | {"VOXSHAPE_MTLS": "true"},
            "cannot use mutual TLS",
        ),
    ):
        with pytest.raises(ConfigError, match=error):
            secured(bus_config("router", env=env), argparse.Namespace(), env)


def test_compose_meshes_its_router_only_when_given_one_to_connect_to(tmp_path):
    """compose.yaml's router meshes when given VOXSHAPE_ROUTER_CONNECT (and _USER), else not."""
    access, kit = mesh_kit(tmp_path)

    def router_env(**variables: str) -> dict[str, str]:
        services = load_topology(COMPOSE, local_variables(variables))
        (spec,) = [s for s in services if s.name == "router"]
        return {**spec.environment, "VOXSHAPE_ACCESS": str(access)}

    assert bus_config("router", env=router_env()).connect == ()
    env = router_env(
        VOXSHAPE_ROUTER_CONNECT="tls/lab-a.example:7448",
        VOXSHAPE_ROUTER_USER="siteb",
        VOXSHAPE_SECRETS=str(kit),
    )
    meshed, note = secured(bus_config("router", env=env), argparse.Namespace(), env)
    assert (meshed.connect, meshed.user) == (("tls/lab-a.example:7448",), "siteb")
    assert meshed.password and "logs in to tls/lab-a.example:7448 as siteb" in note

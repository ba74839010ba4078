"""`voxshape router`: the zenoh router of a session (a Python process in router mode).

Inputs: none. Outputs: none. It routes every other node's traffic: local services and remote
teachers and robots connect to it. It holds the presence token `presence/router/<node>`.

Open by default (the local session on loopback). Secured when given users:

    voxshape router --secrets deploy/secrets --listen tcp/0.0.0.0:7447,tls/0.0.0.0:7448

- **who**: DIR/credentials (or --credentials / VOXSHAPE_CREDENTIALS), `user:password` lines;
  a wrong password is refused when the session opens;
- **what**: the access file (--access / VOXSHAPE_ACCESS, default deploy/access.toml) gives
  each user a role; everything else is denied (services/deploy/access.py);
- **TLS**: tls/ endpoints with DIR/router.pem and .key; with --mtls only clients holding a
  certificate signed by DIR/ca.pem get in.

Security lives here, at the router: services and teachers must then be its clients
(`--mode client`), never peers that could talk to each other around it.
"""

from __future__ import annotations

import argparse
import atexit
import json
import os
import shutil
import tempfile
from dataclasses import replace
from pathlib import Path

from services.deploy.access import (
    ACCESS_FILE,
    AccessError,
    access_control,
    check_consistent,
    find_access_file,
    load_access,
    load_credentials,
)
from services.runtime import BusConfig, ConfigError, Node, Presence, bus_config, fields
from services.runtime.config import add_bus_arguments

LOOPBACK = ("tcp/127.", "tcp/localhost:", "tls/127.", "tls/localhost:", "tcp/[::1]")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    g = parser.add_argument_group("security (off unless users are given)")
    g.add_argument(
        "--credentials",
        type=Path,
        help="user:password lines (VOXSHAPE_CREDENTIALS; default: SECRETS/credentials)",
    )
    g.add_argument(
        "--access",
        type=Path,
        help=f"users' roles (VOXSHAPE_ACCESS; default: {ACCESS_FILE} when secured)",
    )
    g.add_argument(
        "--print-access",
        action="store_true",
        help="print zenoh's access_control settings that the router would use, and exit",
    )


def secured(bus: BusConfig, args: argparse.Namespace, env: dict[str, str]) -> tuple[BusConfig, str]:
    """The router's configuration with authentication and access control when users are
    given, and a line saying what is on."""
    credentials = getattr(args, "credentials", None) or env.get("VOXSHAPE_CREDENTIALS") or None
    if credentials is None and bus.secrets is not None:
        credentials = bus.secrets / "credentials"
    access = getattr(args, "access", None) or env.get("VOXSHAPE_ACCESS") or None
    if bus.mtls and bus.tls_root_ca is None:
        raise ConfigError("mutual TLS needs the CA that signs clients: --tls-root-ca (or SECRETS)")
    tls = [e for e in bus.listen if e.startswith(("tls/", "quic/"))]
    if tls and bus.tls_cert is None:
        raise ConfigError(
            f"listening on {', '.join(tls)} needs the router's certificate: --tls-cert and "
            "--tls-key (or --secrets DIR made by `voxshape certs DIR`)"
        )
    if credentials is None:
        if access is not None:
            raise ConfigError("--access needs the users' passwords: --credentials FILE")
        exposed = [e for e in bus.listen if not e.startswith(LOOPBACK)]
        note = "open: no credentials, no access control"
        if exposed:
            note += f" (WARNING: anyone reaching {', '.join(exposed)} may do anything)"
        return bus, note
    try:
        users = load_access(Path(access) if access else find_access_file())
        passwords = load_credentials(Path(credentials))
    except AccessError as e:
        raise ConfigError(str(e)) from None
    for warning in check_consistent(users, passwords):
        print(f"voxshape router: warning: {warning}", flush=True)
    dictionary = _private_copy(passwords)
    extra = (
        ("transport/auth/usrpwd/dictionary_file", json.dumps(str(dictionary))),
        ("access_control", json.dumps(access_control(bus.session, users))),
    )
    roles = ", ".join(f"{name} ({user.role})" for name, user in users.items())
    note = f"secured: {len(passwords)} password(s), deny by default; roles: {roles}"
    if tls:
        note += f"; TLS on {', '.join(tls)}" + (" (mutual)" if bus.mtls else "")
    return replace(bus, extra=bus.extra + extra), note


def _private_copy(passwords: dict[str, str]) -> Path:
    """zenoh reads bare `user:password` lines only (no comments): a copy only we can read,
    removed when the process ends."""
    folder = Path(tempfile.mkdtemp(prefix="voxshape-router-"))
    path = folder / "credentials"
    descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(descriptor, "w") as f:
        f.write("".join(f"{user}:{password}\n" for user, password in passwords.items()))
    atexit.register(shutil.rmtree, folder, True)
    return path


def run(args: argparse.Namespace) -> int:
    bus, note = secured(bus_config("router", args), args, dict(os.environ))
    if getattr(args, "print_access", False):
        acl = dict(bus.extra).get("access_control")
        print(json.dumps(json.loads(acl), indent=2) if acl else "access control is off: " + note)
        return 0
    with Node("router", bus) as node:
        node.log.info(note)
        node.watch_presence()
        for event in node.events():
            if isinstance(event, Presence) and event.node != node.id:
                verb = "joined" if event.alive else "left"
                node.log.info(f"node {verb}", extra=fields(role=event.role, node=event.node))
    return 0

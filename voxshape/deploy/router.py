"""`voxshape router`: the zenoh router of a session (a Python process in router mode).

Its flows are its `router` row of voxshape/protocol/dataflow.py
(`voxshape dataflow --docstring router`).

It routes every other node's traffic: local services and remote
teachers and robots connect to it. It holds the presence token `presence/router/<node>`.

Open by default (the local session on loopback). Secured when given users:

    voxshape router --secrets deploy/secrets --listen tcp/0.0.0.0:7447,tls/0.0.0.0:7448

- **who**: DIR/credentials (or --credentials / VOXSHAPE_CREDENTIALS), `user:password` lines;
  a wrong password is refused when the session opens;
- **what**: the access file (--access / VOXSHAPE_ACCESS, default deploy/access.toml) gives
  each user a role; everything else is denied (voxshape/deploy/access.py). Any user may ask
  which file it enforces (`voxshape/<session>/router/access`: its path and SHA-256;
  voxshape/protocol/queries.py): `voxshape web` compares it with its own at start;
- **TLS**: tls/ endpoints with DIR/router.pem and .key; with --mtls only clients holding a
  certificate signed by DIR/ca.pem get in.

Security lives here, at the router: services and teachers must then be its clients
(`--mode client`), never peers that could talk to each other around it.

Two sites, one session: `--connect` makes the router also connect to another site's router
(`voxshape router --connect tcp/lab-a.example:7447`), and the two route between their clients.
It serves its own site at once and keeps trying the other (also after a lost link). Secured,
both sites' routers come from one `voxshape certs` kit: the connecting router logs in over
tls/ as --user, an admin of the other's access file, and admits the other router by its
certificate (docs/deployment.md, "Two labs, one session").
"""

from __future__ import annotations

import argparse
import atexit
import json
import os
import shutil
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

from voxshape.deploy.access import (
    ACCESS_FILE,
    AccessError,
    User,
    access_control,
    check_consistent,
    find_access_file,
    load_access,
    load_credentials,
)
from voxshape.deploy.enforced import serve_access
from voxshape.runtime import BusConfig, ConfigError, Node, Presence, bus_config, fields
from voxshape.runtime.config import add_bus_arguments
from voxshape.runtime.settings import add_options, option, read_options
from voxshape.runtime.settings_file import write_run_settings

ROUTER_NAME = "router"  # the common name of a router's certificate (voxshape certs)
LOOPBACK = ("tcp/127.", "tcp/localhost:", "tls/127.", "tls/localhost:", "tcp/[::1]")


@dataclass(frozen=True)
class RouterOptions:
    """`voxshape router`'s security settings (off unless users are given)."""

    credentials: Path | None = option(
        None,
        "user:password lines",
        env="VOXSHAPE_CREDENTIALS",
        show="SECRETS/credentials",
    )
    access: Path | None = option(
        None,
        "users' roles",
        env="VOXSHAPE_ACCESS",
        show=f"{ACCESS_FILE} when secured",
    )
    print_access: bool = option(
        False,
        "print zenoh's access_control settings that the router would use, and exit",
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    add_options(parser, RouterOptions, "security (off unless users are given)")


def secured(bus: BusConfig, args: argparse.Namespace, env: dict[str, str]) -> tuple[BusConfig, str]:
    """The router's configuration with authentication and access control when users are
    given, and a line saying what is on."""
    credentials, _ = _given(bus, args, env)
    if bus.mtls and bus.tls_root_ca is None:
        raise ConfigError("mutual TLS needs the CA that signs clients: --tls-root-ca (or SECRETS)")
    tls = [e for e in bus.listen if e.startswith(("tls/", "quic/"))]
    if tls and bus.tls_cert is None:
        raise ConfigError(
            f"listening on {', '.join(tls)} needs the router's certificate: --tls-cert and "
            "--tls-key (or --secrets DIR made by `voxshape certs DIR`)"
        )
    if credentials is None:
        if getattr(args, "access", None):  # VOXSHAPE_ACCESS alone (compose sets it): open
            raise ConfigError("--access needs the users' passwords: --credentials FILE")
        exposed = [e for e in bus.listen if not e.startswith(LOOPBACK)]
        note = "open: no credentials, no access control"
        if exposed:
            note += f" (WARNING: anyone reaching {', '.join(exposed)} may do anything)"
        return bus, note
    try:
        users = load_access(enforced_access(bus, args, env))
        passwords = load_credentials(credentials)
    except AccessError as e:
        raise ConfigError(str(e)) from None
    for warning in check_consistent(users, passwords):
        print(f"voxshape router: warning: {warning}", flush=True)
    acl = access_control(bus.session, users)
    if bus.connect:
        acl = _admit_other_routers(bus, users, acl)
    dictionary = _private_copy(passwords)
    extra = (
        ("transport/auth/usrpwd/dictionary_file", json.dumps(str(dictionary))),
        ("access_control", json.dumps(acl)),
    )
    roles = ", ".join(f"{name} ({user.role})" for name, user in users.items())
    note = f"secured: {len(passwords)} password(s), deny by default; roles: {roles}"
    if tls:
        note += f"; TLS on {', '.join(tls)}" + (" (mutual)" if bus.mtls else "")
    if bus.connect:
        note += f"; logs in to {', '.join(bus.connect)} as {bus.user}"
    return replace(bus, extra=bus.extra + extra), note


def _given(
    bus: BusConfig, args: argparse.Namespace, env: dict[str, str]
) -> tuple[Path | None, Path | None]:
    """The credentials and access files given (flags, variables, the secrets folder)."""
    options = read_options(RouterOptions, args, env)
    credentials = options.credentials
    if credentials is None and bus.secrets is not None:
        credentials = bus.secrets / "credentials"
    return credentials, options.access


def enforced_access(bus: BusConfig, args: argparse.Namespace, env: dict[str, str]) -> Path | None:
    """The access file a router of these settings enforces; None: open (no credentials)."""
    credentials, access = _given(bus, args, env)
    if credentials is None:
        return None
    try:
        return access or find_access_file()
    except AccessError as e:
        raise ConfigError(str(e)) from None


def _admit_other_routers(bus: BusConfig, users: dict[str, User], acl: dict) -> dict:
    """A secured router that meshes with another site's: it logs in there as --user (an admin
    of that site's access file) over TLS, and lets in whatever comes back over that link,
    which the other router's certificate (common name `router`, from the same `voxshape
    certs` kit) identifies. Each site's own access control has checked its own users."""
    plain = [e for e in bus.connect if not e.startswith("tls/")]
    if plain:
        raise ConfigError(
            f"a secured router meshes over tls/ only ({', '.join(plain)}): its password and "
            "the sessions' traffic would cross between the sites in clear"
        )
    if bus.user is None:
        raise ConfigError(
            "a secured router logs in to the other site's router: give --user (an admin in "
            "that site's access file) and its password (VOXSHAPE_PASSWORD or --password-file)"
        )
    if bus.tls_root_ca is None:
        raise ConfigError("meshing over tls/ needs the CA of the other router: --tls-root-ca")
    if bus.mtls:
        raise ConfigError(
            "a router meshing with another site's cannot use mutual TLS yet (it shows the "
            "other router no client certificate): VOXSHAPE_MTLS=false at this site"
        )
    if ROUTER_NAME in users:
        raise ConfigError(
            f"the access file has a user {ROUTER_NAME!r}: its certificate would pass for the "
            "other site's router; rename that user"
        )
    other = access_control(bus.session, {ROUTER_NAME: User(ROUTER_NAME, "admin")})
    (policy,) = other["policies"]
    shared = {r["id"] for r in acl["rules"]}
    subject = {"id": "router:other-site", "cert_common_names": [ROUTER_NAME]}
    return {
        **acl,
        "rules": acl["rules"] + [r for r in other["rules"] if r["id"] not in shared],
        "subjects": [*acl["subjects"], subject],
        "policies": [*acl["policies"], {**policy, "subjects": [subject["id"]]}],
    }


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
    given, env = bus_config("router", args), dict(os.environ)
    bus, note = secured(given, args, env)
    options = read_options(RouterOptions, args, env)
    if options.print_access:
        acl = dict(bus.extra).get("access_control")
        print(json.dumps(json.loads(acl), indent=2) if acl else "access control is off: " + note)
        return 0
    write_run_settings(given, "router", options)
    with Node("router", bus) as node:
        node.log.info(note)
        answering = serve_access(
            node.zenoh, node.session_id, node.id, enforced_access(given, args, env)
        )
        if bus.connect:  # another site's router: it shows up as "node joined role=router"
            node.log.info(f"meshing with {', '.join(bus.connect)}: tried until it answers")
        node.watch_presence()
        for event in node.events():
            if isinstance(event, Presence) and event.node != node.id:
                verb = "joined" if event.alive else "left"
                node.log.info(f"node {verb}", extra=fields(role=event.role, node=event.node))
        answering.undeclare()
    return 0

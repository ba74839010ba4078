"""How a service joins the bus: one BusConfig, read from VOXSHAPE_* variables and flags.

The embedded default is the local session of this machine: a peer on loopback that connects
to the session router at tcp/127.0.0.1:7447, with multicast scouting off so nothing leaves
the host. Remote teachers and robots use `--mode client --connect tcp/HOST:7447` (or tls/...).

| variable                    | flag              | default                                 |
|-----------------------------|-------------------|-----------------------------------------|
| VOXSHAPE_SESSION            | --session         | default                                 |
| VOXSHAPE_NODE               | --node            | <role>-<hostname>-<pid>                 |
| VOXSHAPE_MODE               | --mode            | peer (router for `voxshape router`)     |
| VOXSHAPE_CONNECT            | --connect         | tcp/127.0.0.1:7447 (none for a router)  |
| VOXSHAPE_LISTEN             | --listen          | tcp/127.0.0.1:0 (router: ...:7447)      |
| VOXSHAPE_CONNECT_TIMEOUT    | --connect-timeout | 10 (seconds to reach a router at start) |
| VOXSHAPE_USER               | --user            | (none)                                  |
| VOXSHAPE_PASSWORD(_FILE)    | --password-file   | (none; voxshape teach asks in a terminal) |
| VOXSHAPE_TLS_ROOT_CA        | --tls-root-ca     | (none)                                  |
| VOXSHAPE_TLS_CERT / _KEY    | --tls-cert/-key   | (none; needed for TLS listen and mTLS)  |
| VOXSHAPE_MTLS               | --mtls            | false                                   |
| VOXSHAPE_SECRETS            | --secrets         | (none; from `voxshape certs DIR`)       |
Lists are comma-separated.

VOXSHAPE_PASSWORD_FILE holds the password, or is a credentials file of `user:password` lines
(the line of VOXSHAPE_USER is taken). VOXSHAPE_SECRETS fills in whatever was not given: the
user is the role (`sim`, `learner`, `logger`...), its password is its line of DIR/credentials,
the CA is DIR/ca.pem, this node's certificate DIR/<user>.pem and .key (a router's:
DIR/router.pem and .key, and DIR/credentials is the users it accepts, and has the password
of the user it logs in as at another site's router: see services/router.py).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import socket
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import zenoh

from protocol import ProtocolError, check_id

Mode = Literal["peer", "client", "router"]
MODES: tuple[Mode, ...] = ("peer", "client", "router")
LOCAL_ROUTER = "tcp/127.0.0.1:7447"
_ENDPOINT = re.compile(r"(tcp|udp|tls|quic|ws|unixsock-stream)/[^\s#?]+")


class ConfigError(ValueError):
    """A setting that cannot work; the message names the setting and how to fix it."""


@dataclass(frozen=True)
class BusConfig:
    session: str = "default"
    node: str | None = None
    mode: Mode = "peer"
    connect: tuple[str, ...] = (LOCAL_ROUTER,)
    listen: tuple[str, ...] = ("tcp/127.0.0.1:0",)
    connect_timeout: float = 10.0
    user: str | None = None
    password: str | None = None
    tls_root_ca: Path | None = None
    tls_cert: Path | None = None
    tls_key: Path | None = None
    mtls: bool = False
    secrets: Path | None = None
    # zenoh settings a role adds, as (path, JSON5), e.g. the router's access control.
    extra: tuple[tuple[str, str], ...] = ()

    @classmethod
    def for_role(cls, role: str) -> BusConfig:
        """Defaults of a role before variables and flags apply (a router listens on 7447)."""
        if role == "router":
            return cls(mode="router", connect=(), listen=(LOCAL_ROUTER,))
        return cls()

    def validated(self) -> BusConfig:
        try:
            check_id(self.session, "session")
            if self.node is not None:
                check_id(self.node, "node")
        except ProtocolError as e:
            raise ConfigError(f"{e} (set with --{e.field} or VOXSHAPE_{e.field.upper()})") from None
        if self.mode not in MODES:
            raise ConfigError(f"mode {self.mode!r} is not one of {', '.join(MODES)}")
        for endpoint in (*self.connect, *self.listen):
            if not _ENDPOINT.fullmatch(endpoint):
                raise ConfigError(
                    f"endpoint {endpoint!r} is not PROTOCOL/HOST:PORT, e.g. tcp/127.0.0.1:7447"
                )
        if self.mode == "client" and not self.connect:
            raise ConfigError("client mode needs a router to connect to: set --connect")
        if self.connect_timeout <= 0:
            raise ConfigError(f"connect timeout {self.connect_timeout} must be > 0 seconds")
        if self.user is not None and self.password is None:
            raise ConfigError(
                f"user {self.user!r} needs its password: set VOXSHAPE_PASSWORD, give "
                "--password-file FILE (VOXSHAPE_PASSWORD_FILE: the password, or user:password "
                "lines), or run `voxshape teach` in a terminal, which asks for it; the "
                "session's admin has it (the user's line of the secrets folder's credentials)"
            )
        if self.password is not None and self.user is None:
            raise ConfigError("a password without a user: give --user (VOXSHAPE_USER) too")
        for name in ("tls_root_ca", "tls_cert", "tls_key"):
            path = getattr(self, name)
            if path is not None and not Path(path).is_file():
                raise ConfigError(f"{name.replace('_', '-')} file {str(path)!r} does not exist")
        if (self.tls_cert is None) != (self.tls_key is None):
            raise ConfigError("--tls-cert and --tls-key go together")
        if self.mtls and self.tls_cert is None:
            raise ConfigError("mutual TLS needs this node's certificate: --tls-cert/--tls-key")
        uses_tls = any(e.startswith(("tls/", "quic/")) for e in (*self.connect, *self.listen))
        if uses_tls and self.tls_root_ca is None and self.mode != "router":
            raise ConfigError("a tls/ endpoint needs the CA certificate: --tls-root-ca")
        return self

    def zenoh_config(self) -> zenoh.Config:
        """The zenoh configuration, explicit in every setting this project relies on."""
        retry = {"period_init_ms": 100, "period_max_ms": 500, "period_increase_factor": 2}
        conf: dict = {
            "mode": self.mode,
            "scouting": {"multicast": {"enabled": False}},
            "connect": {
                "endpoints": list(self.connect),
                "timeout_ms": int(self.connect_timeout * 1000),
                "exit_on_failure": True,
                "retry": retry,
            },
            "listen": {"endpoints": list(self.listen) if self.mode != "client" else []},
            # One host, heavy CPU contention: shared memory lost samples (zenoh issue 2628).
            "transport": {"shared_memory": {"enabled": False}},
        }
        if self.mode == "router":
            conf["listen"]["exit_on_failure"] = True
            conf["timestamping"] = {"enabled": True}
            # A router that also connects meshes with another site's router: it serves its
            # own site at once and keeps trying the other in the background (every 100-500
            # ms), also after a lost link. Gossip stays zenoh's (on, one hop): the router
            # brokers between its peers with it (without, peers of one router hear nothing).
            conf["connect"]["exit_on_failure"] = False
        if self.user is not None:
            conf["transport"]["auth"] = {"usrpwd": {"user": self.user, "password": self.password}}
        tls: dict = {}
        if self.tls_root_ca is not None:
            tls["root_ca_certificate"] = str(self.tls_root_ca)
        if self.tls_cert is not None:
            side = "listen" if self.mode == "router" else "connect"
            tls[f"{side}_certificate"] = str(self.tls_cert)
            tls[f"{side}_private_key"] = str(self.tls_key)
        if self.mtls:
            tls["enable_mtls"] = True
        if tls:
            conf["transport"]["link"] = {"tls": tls}
        config = zenoh.Config.from_json5(json.dumps(conf))
        for path, value in self.extra:
            config.insert_json5(path, value)
        return config


def tcp_address(endpoint: str) -> tuple[str, int] | None:
    """(host, port) of a tcp/ or tls/ endpoint, its zenoh metadata (?... #...) aside; None
    for other protocols or no port. The host is bare: an IPv6 one without its brackets."""
    protocol, _, address = endpoint.partition("/")
    host, _, port = address.split("#")[0].split("?")[0].rpartition(":")
    if protocol not in ("tcp", "tls") or not port.isdigit():
        return None
    return host.strip("[]"), int(port)


def wait_for_loopback_port(port: int, timeout: float = 15.0) -> None:
    """Until something listens on 127.0.0.1:`port`; TimeoutError after `timeout` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.05)
    raise TimeoutError(f"nothing listening on 127.0.0.1:{port} after {timeout} s")


def free_loopback_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def add_bus_arguments(
    parser: argparse.ArgumentParser, renamed: Mapping[str, str] | None = None
) -> None:
    """The flags every service shares; unset flags fall back to VOXSHAPE_* variables.
    `renamed` gives `mode` and `connect` other flags, for a command whose own flags take
    those names (`voxshape ros2 --connect ROBOT --mode ros2dds --bus ...`)."""
    flag = {"mode": "--mode", "connect": "--connect", **(renamed or {})}
    g = parser.add_argument_group("bus (flags override VOXSHAPE_* variables)")
    g.add_argument("--session", help="session id (VOXSHAPE_SESSION; default: default)")
    g.add_argument("--node", help="this node's id (VOXSHAPE_NODE; default: role-host-pid)")
    g.add_argument(flag["mode"], dest="mode", choices=MODES, help="zenoh mode (VOXSHAPE_MODE)")
    g.add_argument(
        flag["connect"],
        dest="connect",
        help="comma-separated endpoints of the session's router, e.g. tcp/10.0.0.2:7447 "
        "(VOXSHAPE_CONNECT)",
    )
    g.add_argument("--listen", help="comma-separated endpoints to listen on")
    g.add_argument("--connect-timeout", type=float, help="seconds to wait for the router")
    g.add_argument(
        "--user",
        help="user name for the router; its password from VOXSHAPE_PASSWORD, --password-file "
        "or, for voxshape teach in a terminal, asked for",
    )
    g.add_argument(
        "--password-file",
        type=Path,
        help="file with the user's password, or user:password lines (VOXSHAPE_PASSWORD_FILE)",
    )
    g.add_argument("--tls-root-ca", type=Path, help="CA certificate for tls/ endpoints")
    g.add_argument("--tls-cert", type=Path, help="this node's certificate (TLS listen, mTLS)")
    g.add_argument("--tls-key", type=Path, help="this node's private key")
    g.add_argument("--mtls", action="store_true", default=None, help="mutual TLS")
    g.add_argument(
        "--secrets", type=Path, help="folder of credentials and certificates (voxshape certs)"
    )


def _endpoints(value: str) -> tuple[str, ...]:
    return tuple(e.strip() for e in value.split(",") if e.strip())


def bus_config(
    role: str,
    args: argparse.Namespace | None = None,
    env: Mapping[str, str] = os.environ,
    ask: Callable[[str], str] | None = None,
) -> BusConfig:
    """Role defaults, then VOXSHAPE_* variables, then flags; validated. A user given without
    a password is asked for it with `ask` (a prompt), if given."""
    config = BusConfig.for_role(role)
    settings: dict = {}
    for name, parse in (
        ("session", str),
        ("node", str),
        ("mode", str),
        ("connect", _endpoints),
        ("listen", _endpoints),
        ("connect_timeout", float),
        ("user", str),
        ("password", str),
        ("tls_root_ca", Path),
        ("tls_cert", Path),
        ("tls_key", Path),
        ("mtls", lambda v: v.strip().lower() in ("1", "true", "yes", "on")),
        ("secrets", Path),
    ):
        variable = f"VOXSHAPE_{name.upper()}"
        flag = getattr(args, name, None) if args is not None else None
        raw = flag if flag is not None else env.get(variable)
        if raw is None or raw == "":
            continue
        try:
            settings[name] = parse(raw) if isinstance(raw, str) else raw
        except ValueError:
            raise ConfigError(
                f"{variable}={raw!r} is not a valid {name.replace('_', ' ')}"
            ) from None
    flag = getattr(args, "password_file", None)
    password_file, what = (flag, "--password-file") if flag else (None, "")
    if not password_file and env.get("VOXSHAPE_PASSWORD_FILE"):
        password_file, what = env["VOXSHAPE_PASSWORD_FILE"], "VOXSHAPE_PASSWORD_FILE"
    if "password" not in settings and password_file:
        settings["password"] = _password(Path(password_file), settings.get("user"), what)
    if settings.get("secrets") is not None:
        _fill_from_secrets(role, settings)
    if settings.get("user") is not None and "password" not in settings and ask is not None:
        settings["password"] = ask(f"password for {settings['user']}: ")
    return replace(config, **settings).validated()


def _password(path: Path, user: str | None, what: str) -> str:
    """The password in `path`: the line `user:password` of this user, else the one line."""
    try:
        lines = [line.strip() for line in path.read_text().splitlines() if line.strip()]
    except OSError as e:
        raise ConfigError(f"{what} {str(path)!r}: {e.strerror}") from None
    for line in lines:
        name, colon, password = line.partition(":")
        if colon and name == user:
            return password
    if len(lines) == 1:
        return lines[0]
    raise ConfigError(
        f"{what} {str(path)!r} has no line {user or '<user>'}:<password>: "
        "set VOXSHAPE_USER, or add the user with `voxshape certs`"
    )


def _fill_from_secrets(role: str, settings: dict) -> None:
    """What a folder made by `voxshape certs` provides, where not given explicitly."""
    folder = Path(settings["secrets"])
    if not folder.is_dir():
        raise ConfigError(
            f"VOXSHAPE_SECRETS {str(folder)!r} is not a folder: make one with `voxshape certs "
            f"{folder}`"
        )
    if role == "router":
        identity = "router"
        if settings.get("user") is not None and "password" not in settings:
            settings["password"] = _password(  # its login at another site's router
                folder / "credentials", settings["user"], "VOXSHAPE_SECRETS credentials file"
            )
    else:
        settings.setdefault("user", role)
        identity = settings["user"]
        if "password" not in settings:
            settings["password"] = _password(
                folder / "credentials", identity, "VOXSHAPE_SECRETS credentials file"
            )
    if "tls_root_ca" not in settings and (folder / "ca.pem").is_file():
        settings["tls_root_ca"] = folder / "ca.pem"
    cert, key = folder / f"{identity}.pem", folder / f"{identity}.key"
    if "tls_cert" not in settings and cert.is_file() and key.is_file():
        settings["tls_cert"], settings["tls_key"] = cert, key

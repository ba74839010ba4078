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
of the user it logs in as at another site's router: see voxshape/deploy/router.py).
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

from voxshape.protocol import ProtocolError, check_id
from voxshape.runtime.settings import ConfigError, add_options, option, read_options

Mode = Literal["peer", "client", "router"]
MODES: tuple[Mode, ...] = ("peer", "client", "router")
LOCAL_ROUTER = "tcp/127.0.0.1:7447"
_ENDPOINT = re.compile(r"(tcp|udp|tls|quic|ws|unixsock-stream)/[^\s#?]+")

# No publisher waits for a slow subscriber (voxshape/protocol/dataflow.py DELIVERY): what a queue
# cannot take at once is dropped for that subscriber alone, after waiting this long. A node's own
# queue to its router fills only when the node's sending thread is starved: zenoh's 1 ms then
# dropped a lockstep learner's actions on a loaded machine (the robot stood for its action
# timeout). Routers keep zenoh's 1 ms: a router waiting longer on the queue of a subscriber
# that stopped reading slowed every publisher behind it (docs/decisions.md, 2026-11-28).
DROP_WAIT = {"drop": {"wait_before_drop": 50_000}}  # microseconds
# Each message leaves as a batch of its own (express): zenoh's 4 batches of data a link held a
# burst of 4 (a teacher's audio, a test's every type at once); 16 is its most.
DATA_QUEUE = 16


def _endpoints(value: str) -> tuple[str, ...]:
    return tuple(e.strip() for e in value.split(",") if e.strip())


@dataclass(frozen=True)
class BusConfig:
    session: str = option("default", "session id", env="VOXSHAPE_SESSION")
    node: str | None = option(None, "this node's id", env="VOXSHAPE_NODE", show="role-host-pid")
    mode: Mode = option("peer", "zenoh mode", env="VOXSHAPE_MODE")
    connect: tuple[str, ...] = option(
        (LOCAL_ROUTER,),
        "comma-separated endpoints of the session's router, e.g. tcp/10.0.0.2:7447",
        env="VOXSHAPE_CONNECT",
        parse=_endpoints,
    )
    listen: tuple[str, ...] = option(
        ("tcp/127.0.0.1:0",),
        "comma-separated endpoints to listen on",
        env="VOXSHAPE_LISTEN",
        parse=_endpoints,
    )
    connect_timeout: float = option(
        10.0, "seconds to wait for the router", env="VOXSHAPE_CONNECT_TIMEOUT"
    )
    user: str | None = option(
        None,
        "user name for the router; its password from VOXSHAPE_PASSWORD, --password-file or, "
        "for voxshape teach in a terminal, asked for",
        env="VOXSHAPE_USER",
    )
    password: str | None = option(None, "the user's password", env="VOXSHAPE_PASSWORD", flag=None)
    password_file: Path | None = option(
        None,
        "file with the user's password, or user:password lines",
        env="VOXSHAPE_PASSWORD_FILE",
    )
    tls_root_ca: Path | None = option(
        None, "CA certificate for tls/ endpoints", env="VOXSHAPE_TLS_ROOT_CA"
    )
    tls_cert: Path | None = option(
        None, "this node's certificate (TLS listen, mTLS)", env="VOXSHAPE_TLS_CERT"
    )
    tls_key: Path | None = option(None, "this node's private key", env="VOXSHAPE_TLS_KEY")
    mtls: bool = option(False, "mutual TLS", env="VOXSHAPE_MTLS")
    secrets: Path | None = option(
        None,
        "folder of credentials and certificates (voxshape certs)",
        env="VOXSHAPE_SECRETS",
    )
    # zenoh settings a role adds, as (path, JSON5), e.g. the router's access control.
    extra: tuple[tuple[str, str], ...] = ()
    # the command's flag of `connect`, for what a user is told (`voxshape ros2`'s is --bus)
    connect_flag: str = "--connect"
    # a router port of this host that refuses is said at once, not waited for (a person's
    # tools, when no connect timeout was given: one given is a wish to wait)
    fail_fast: bool = False

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
            "transport": {
                "shared_memory": {"enabled": False},
                "link": {"tx": {"queue": {"size": {"data": DATA_QUEUE}}}},
            },
        }
        if self.mode != "router":
            conf["transport"]["link"]["tx"]["queue"]["congestion_control"] = DROP_WAIT
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
            conf["transport"]["link"]["tls"] = tls
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
    """The flags every service shares, from BusConfig's fields; unset flags fall back to
    VOXSHAPE_* variables. `renamed` gives `mode` and `connect` other flags, for a command
    whose own flags take those names (`voxshape ros2 --connect ROBOT --mode ros2dds --bus ...`)."""
    add_options(parser, BusConfig, "bus (flags override VOXSHAPE_* variables)", renamed)
    parser.set_defaults(bus_connect_flag=(renamed or {}).get("connect", "--connect"))


def bus_config(
    role: str,
    args: argparse.Namespace | None = None,
    env: Mapping[str, str] = os.environ,
    ask: Callable[[str], str] | None = None,
    fail_fast: bool = False,
) -> BusConfig:
    """Role defaults, then VOXSHAPE_* variables, then flags; validated. A user given without
    a password is asked for it with `ask` (a prompt), if given. `fail_fast`: a refusing router
    port of this host ends the wait at once, unless a connect timeout was given."""
    config = read_options(BusConfig, args, env, base=BusConfig.for_role(role))
    if flag := getattr(args, "bus_connect_flag", None):
        config = replace(config, connect_flag=flag)
    waits = getattr(args, "connect_timeout", None) is not None or env.get(
        "VOXSHAPE_CONNECT_TIMEOUT"
    )
    config = replace(config, fail_fast=fail_fast and not waits)
    if config.password is None and config.password_file is not None:
        given = getattr(args, "password_file", None) is not None
        what = "--password-file" if given else "VOXSHAPE_PASSWORD_FILE"
        password = _password(config.password_file, config.user, what)
        config = replace(config, password=password)
    if config.secrets is not None:
        config = _fill_from_secrets(role, config)
    if config.user is not None and config.password is None and ask is not None:
        config = replace(config, password=ask(f"password for {config.user}: "))
    return config.validated()


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


def _fill_from_secrets(role: str, config: BusConfig) -> BusConfig:
    """What a folder made by `voxshape certs` provides, where not given explicitly."""
    folder = Path(config.secrets or "")
    if not folder.is_dir():
        raise ConfigError(
            f"VOXSHAPE_SECRETS {str(folder)!r} is not a folder: make one with `voxshape certs "
            f"{folder}`"
        )
    credentials = folder / "credentials"
    what = "VOXSHAPE_SECRETS credentials file"
    user, password = config.user, config.password
    if role == "router":
        identity = "router"
        if user is not None and password is None:  # its login at another site's router
            password = _password(credentials, user, what)
    else:
        user = identity = user or role
        if password is None:
            password = _password(credentials, identity, what)
    found: dict = {}
    if config.tls_root_ca is None and (folder / "ca.pem").is_file():
        found["tls_root_ca"] = folder / "ca.pem"
    cert, key = folder / f"{identity}.pem", folder / f"{identity}.key"
    if config.tls_cert is None and cert.is_file() and key.is_file():
        found["tls_cert"], found["tls_key"] = cert, key
    return replace(config, user=user, password=password, **found)

"""`voxshape web`: the teachers' web page, an aiohttp server bridged to the bus.

    GET /        the page (voxshape/services/web/static/index.html) and its files
    GET /ws      the WebSocket of docs/web.md: login, then JSON and audio frames

Its own node, role "web":

Its flows are its `web` row of voxshape/protocol/dataflow.py
(`voxshape dataflow --docstring web`).

Each logged-in browser gets a teacher node of its own (role "teacher", the browser's user and
password on a secured session, so the router's access control applies to it as to `voxshape
teach`): outputs teacher/<t>/utterance (typed words, kept) and teacher/<t>/audio, inputs its
notices and utterances, and the clock exchange with the arbiter. The server is
voxshape/services/web/server.py.

On a secured session its teachers come from the access file (--access, VOXSHAPE_ACCESS), which
must be the router's: at start it asks the router which file it enforces
(`voxshape/<session>/router/access`) and stops with an error naming both when they differ.
"""

from __future__ import annotations

import argparse
import asyncio
import socket
import ssl
from dataclasses import dataclass
from pathlib import Path

from voxshape.deploy.access import AccessError, access_digest, find_access_file, load_access
from voxshape.protocol import (
    load_vocabulary,
)
from voxshape.protocol.vocabulary import LANGUAGES
from voxshape.runtime import (
    ConfigError,
    add_bus_arguments,
    bus_config,
)
from voxshape.runtime.settings import add_options, option, read_options
from voxshape.runtime.settings_file import write_run_settings
from voxshape.services.web.admission import (
    AdmissionError,
    Origins,
    public_origin,
)
from voxshape.services.web.page_json import SessionView, map_json, vocabulary_json
from voxshape.services.web.server import PageServer
from voxshape.world.maps import load_map, task_option

STATIC = Path(__file__).with_name("static")
DEFAULT_PORT = 8080
DEFAULT_MAX_CLIENTS = 20
HTTPS = "HTTPS (a certificate and its key, e.g. the router's of `voxshape certs DIR`)"


@dataclass(frozen=True)
class WebOptions:
    """`voxshape web`'s settings: what the page shows, and where and to whom it is served."""

    task: str = task_option("to draw")
    viewer_url: str | None = option(
        None, "the rerun web viewer's address, linked from the page", env="VOXSHAPE_VIEWER_URL"
    )
    language: str = option(
        "en", "the page's first language", env="VOXSHAPE_LANGUAGE", choices=LANGUAGES
    )
    vocabulary: Path | None = option(None, "vocabulary file", show="built in")
    static: Path = option(STATIC, "folder of the page", show="the packaged page")
    address: str = option(
        "127.0.0.1",
        "address to serve the page on (127.0.0.1: this host only; 0.0.0.0 for every interface)",
        env="VOXSHAPE_WEB_ADDRESS",
    )
    port: int = option(DEFAULT_PORT, "port to serve the page on", env="VOXSHAPE_WEB_PORT")
    https_cert: Path | None = option(
        None,
        "the page's certificate (PEM), e.g. DIR/router.pem",
        env="VOXSHAPE_WEB_CERT",
        group=HTTPS,
    )
    https_key: Path | None = option(
        None, "its private key, e.g. DIR/router.key", env="VOXSHAPE_WEB_KEY", group=HTTPS
    )
    max_clients: int = option(
        DEFAULT_MAX_CLIENTS, "browsers at once", env="VOXSHAPE_WEB_MAX_CLIENTS"
    )
    public_origin: str | None = option(
        None,
        "the address teachers open, e.g. https://lab.example:8443: its host is let in besides "
        "loopback names, IP addresses and this machine's names",
        env="VOXSHAPE_WEB_ORIGIN",
    )
    access: Path | None = option(
        None,
        "access file whose teachers may log in on a secured session: the router's own, which "
        "it checks at start",
        env="VOXSHAPE_ACCESS",
        show="deploy/access.toml",
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    add_options(parser, WebOptions)


def run(args: argparse.Namespace) -> int:
    options = read_options(WebOptions, args)
    bus = bus_config("web", args)
    if not 0 <= options.port <= 65535:
        raise ConfigError(f"--port {options.port} is outside 0-65535 (VOXSHAPE_WEB_PORT)")
    if options.max_clients < 1:
        raise ConfigError("--max-clients must be at least 1")
    if (options.https_cert is None) != (options.https_key is None):
        raise ConfigError("--https-cert and --https-key go together")
    tls = None
    if options.https_cert is not None:
        tls = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        try:
            tls.load_cert_chain(options.https_cert, options.https_key)
        except (OSError, ssl.SSLError) as e:
            raise ConfigError(
                f"cannot use {options.https_cert} / {options.https_key} for HTTPS: {e}"
            ) from None
    view = SessionView(
        session=bus.session,
        secured=bus.user is not None,
        language=options.language,
        vocabulary=vocabulary_json(load_vocabulary(options.vocabulary)),
        map=map_json(load_map(options.task)),
        viewer=options.viewer_url,
    )
    if not (options.static / "index.html").is_file():
        raise ConfigError(f"no page to serve: {options.static}/index.html is missing")
    try:
        origins = Origins(
            public_origin(options.public_origin) if options.public_origin else None,
            frozenset(n.lower() for n in (socket.gethostname(), socket.getfqdn()) if n),
        )
        access = (options.access or find_access_file()) if view.secured else None
        teachers = _teachers(access) if access is not None else None
        digest = access_digest(access) if access is not None else None
    except (AdmissionError, AccessError) as e:
        raise ConfigError(str(e)) from None
    write_run_settings(bus, "web", options)
    gateway = PageServer(
        bus, view, options.static, options.address, tls, options.max_clients, origins
    )
    gateway.teachers = teachers
    if access is not None and digest is not None:
        gateway.access = (access, digest)
    asyncio.run(gateway.serve(options.port))
    return 0


def _teachers(path: Path) -> frozenset[str]:
    """The users of the teacher role: the only ones a browser may log in as."""
    users = load_access(path)
    return frozenset(name for name, user in users.items() if user.role == "teacher")

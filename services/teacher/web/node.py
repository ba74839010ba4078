"""`voxshape web`: the teachers' web page, an aiohttp server bridged to the bus.

    GET /        the page (services/teacher/web/static/index.html) and its files
    GET /ws      the WebSocket of docs/web.md: login, then JSON and audio frames

Inputs (its own node, role "web"): voxshape/<session>/robot/*/obs, episode, feedback,
teaching, help (a robot's question) and answer (who answered it). Each logged-in browser gets
a teacher node of its own (role "teacher", the browser's user and password on a secured
session, so the router's access control applies to it as to `voxshape teach`): outputs
teacher/<t>/utterance (typed words, kept) and teacher/<t>/audio, inputs its notices and
utterances, and the clock exchange with the arbiter. The server is
services/teacher/web/server.py.

On a secured session its teachers come from the access file (--access, VOXSHAPE_ACCESS), which
must be the router's: at start it asks the router which file it enforces
(`voxshape/<session>/router/access`) and stops with an error naming both when they differ.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import socket
import ssl
from pathlib import Path

from protocol import (
    load_vocabulary,
)
from protocol.vocabulary import LANGUAGES
from services.deploy.access import AccessError, access_digest, find_access_file, load_access
from services.runtime import (
    ConfigError,
    add_bus_arguments,
    bus_config,
)
from services.teacher.web.admission import (
    AdmissionError,
    Origins,
    public_origin,
)
from services.teacher.web.page_json import SessionView, map_json, vocabulary_json
from services.teacher.web.server import PageServer
from services.world.maps import add_task_argument, load_map

STATIC = Path(__file__).with_name("static")
DEFAULT_PORT = 8080
DEFAULT_MAX_CLIENTS = 20


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_arguments(parser)
    _serving_arguments(parser)
    env = os.environ.get
    add_task_argument(parser, "to draw")
    parser.add_argument(
        "--viewer-url",
        default=env("VOXSHAPE_VIEWER_URL") or None,
        help="the rerun web viewer's address, linked from the page (VOXSHAPE_VIEWER_URL)",
    )
    parser.add_argument(
        "--language",
        choices=LANGUAGES,
        default=env("VOXSHAPE_LANGUAGE", "en"),
        help="the page's first language (VOXSHAPE_LANGUAGE)",
    )
    parser.add_argument("--vocabulary", type=Path, help="vocabulary file (default: built in)")
    parser.add_argument("--static", type=Path, default=STATIC, help="folder of the page")


def _serving_arguments(parser: argparse.ArgumentParser) -> None:
    """Where and how the page is served, and to whom."""
    env = os.environ.get
    parser.add_argument(
        "--address",
        default=env("VOXSHAPE_WEB_ADDRESS", "127.0.0.1"),
        help="address to serve the page on (VOXSHAPE_WEB_ADDRESS; default 127.0.0.1: this "
        "host only; 0.0.0.0 for every interface)",
    )
    parser.add_argument(
        "--port",
        type=int,
        default=int(env("VOXSHAPE_WEB_PORT") or DEFAULT_PORT),
        help=f"(VOXSHAPE_WEB_PORT; default {DEFAULT_PORT})",
    )
    parser.add_argument(
        "--https-cert",
        type=Path,
        default=env("VOXSHAPE_WEB_CERT") or None,
        help="serve HTTPS with this certificate (PEM; VOXSHAPE_WEB_CERT), e.g. the router's "
        "of `voxshape certs DIR`: DIR/router.pem",
    )
    parser.add_argument(
        "--https-key",
        type=Path,
        default=env("VOXSHAPE_WEB_KEY") or None,
        help="its private key (VOXSHAPE_WEB_KEY), e.g. DIR/router.key",
    )
    parser.add_argument(
        "--max-clients",
        type=int,
        default=int(env("VOXSHAPE_WEB_MAX_CLIENTS") or DEFAULT_MAX_CLIENTS),
        help=f"browsers at once (VOXSHAPE_WEB_MAX_CLIENTS; default {DEFAULT_MAX_CLIENTS})",
    )
    parser.add_argument(
        "--public-origin",
        default=env("VOXSHAPE_WEB_ORIGIN") or None,
        help="the address teachers open, e.g. https://lab.example:8443 (VOXSHAPE_WEB_ORIGIN): "
        "its host is let in besides loopback names, IP addresses and this machine's names",
    )
    parser.add_argument(
        "--access",
        type=Path,
        default=env("VOXSHAPE_ACCESS") or None,
        help="access file whose teachers may log in on a secured session (VOXSHAPE_ACCESS; "
        "default deploy/access.toml): the router's own, which it checks at start",
    )


def run(args: argparse.Namespace) -> int:
    bus = bus_config("web", args)
    if not 0 <= args.port <= 65535:
        raise ConfigError(f"--port {args.port} is outside 0-65535 (VOXSHAPE_WEB_PORT)")
    if args.max_clients < 1:
        raise ConfigError("--max-clients must be at least 1")
    if (args.https_cert is None) != (args.https_key is None):
        raise ConfigError("--https-cert and --https-key go together")
    tls = None
    if args.https_cert is not None:
        tls = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        try:
            tls.load_cert_chain(args.https_cert, args.https_key)
        except (OSError, ssl.SSLError) as e:
            raise ConfigError(
                f"cannot use {args.https_cert} / {args.https_key} for HTTPS: {e}"
            ) from None
    view = SessionView(
        session=bus.session,
        secured=bus.user is not None,
        language=args.language,
        vocabulary=vocabulary_json(load_vocabulary(args.vocabulary)),
        map=map_json(load_map(args.task)),
        viewer=args.viewer_url,
    )
    if not (args.static / "index.html").is_file():
        raise ConfigError(f"no page to serve: {args.static}/index.html is missing")
    try:
        origins = Origins(
            public_origin(args.public_origin) if args.public_origin else None,
            frozenset(n.lower() for n in (socket.gethostname(), socket.getfqdn()) if n),
        )
        access = (args.access or find_access_file()) if view.secured else None
        teachers = _teachers(access) if access is not None else None
        digest = access_digest(access) if access is not None else None
    except (AdmissionError, AccessError) as e:
        raise ConfigError(str(e)) from None
    gateway = PageServer(bus, view, args.static, args.address, tls, args.max_clients, origins)
    gateway.teachers = teachers
    if access is not None and digest is not None:
        gateway.access = (access, digest)
    asyncio.run(gateway.serve(args.port))
    return 0


def _teachers(path: Path) -> frozenset[str]:
    """The users of the teacher role: the only ones a browser may log in as."""
    users = load_access(path)
    return frozenset(name for name, user in users.items() if user.role == "teacher")

"""Opening the zenoh session a node runs on, and saying in a user's words why it would not
open: a router that cannot be reached, one that refuses this user, a port already taken."""

from __future__ import annotations

import socket
from dataclasses import replace

import zenoh

from voxshape.runtime.config import BusConfig, tcp_address

LOGIN_WAIT_S = 1.2  # a router that answers lets a good login in within milliseconds


class BusError(RuntimeError):
    """The bus cannot be joined; the message says why and what to do."""


def open_zenoh(config: BusConfig) -> zenoh.Session:
    """Opens a zenoh session, translating zenoh's errors into what a user should do. A user
    whose router answers is either let in within milliseconds or refused: refused, it is told
    so at once, not after the whole connect timeout."""
    if config.fail_fast and config.mode != "router" and _refused_at_once(config.connect):
        raise BusError(
            f"nothing listens at {', '.join(config.connect)} (refused at once). Is the "
            "session's router running? Locally, `voxshape up` starts one; for another "
            f"session's, check {config.connect_flag}/VOXSHAPE_CONNECT (--connect-timeout "
            "waits for one that is starting)."
        )
    answering = config.mode != "router" and _router_answers(config.connect)
    if config.user is not None and answering:
        quick = replace(config, connect_timeout=min(config.connect_timeout, LOGIN_WAIT_S))
        try:
            return zenoh.open(quick.zenoh_config())
        except zenoh.ZError as e:
            if "Unable to connect" not in str(e):
                raise _bus_error(config, str(e)) from None
            tls = any(e.startswith("tls/") for e in config.connect)
            raise BusError(
                f"the router at {', '.join(config.connect)} refused user {config.user!r}: a "
                "wrong password or a user it does not know"
                + (
                    ", or a certificate it does not accept (--tls-root-ca; mutual TLS: "
                    "--tls-cert/--tls-key)"
                    if tls
                    else " (or this port is its TLS endpoint: connect with tls/)"
                )
                + ". Check the password (VOXSHAPE_PASSWORD or VOXSHAPE_PASSWORD_FILE; `voxshape "
                "certs` wrote it in the session's credentials file) with the session's admin; "
                "RUST_LOG=debug shows zenoh's own log of the refusal."
            ) from None
    try:
        return zenoh.open(config.zenoh_config())
    except zenoh.ZError as e:
        raise _bus_error(config, str(e), answering) from None


def _bus_error(config: BusConfig, text: str, answering: bool = False) -> BusError:
    if "Unable to connect" in text:
        if answering:
            return BusError(
                f"the router at {', '.join(config.connect)} answers but refused this session "
                f"within {config.connect_timeout:g} s: a secured router needs a user and its "
                "password (--user, VOXSHAPE_PASSWORD) and, on tls/, --tls-root-ca"
            )
        return BusError(
            f"cannot reach {', '.join(config.connect)} within {config.connect_timeout:g} s. "
            "Is the session's router running? Locally, `voxshape up` starts one; remotely, "
            f"check {config.connect_flag}/VOXSHAPE_CONNECT and the credentials."
        )
    if "listen" in text.lower() or "address" in text.lower():
        return BusError(
            f"cannot listen on {', '.join(config.listen)}: {text.split(' at ')[0]}. "
            "Is another router already using it? Choose another with --listen."
        )
    return BusError(f"zenoh refused to open the session: {text.split(' at ')[0]}")


def _router_answers(endpoints: tuple[str, ...], timeout: float = 0.5) -> bool:
    """Whether something accepts TCP connections at one of the tcp/ or tls/ endpoints."""
    for address in filter(None, map(tcp_address, endpoints)):
        try:
            with socket.create_connection(address, timeout=timeout):
                return True
        except OSError:
            continue
    return False


LOOPBACK = ("127.", "::1", "localhost")


def _refused_at_once(endpoints: tuple[str, ...]) -> bool:
    """Whether every endpoint is a port of this host that refuses connections now: nothing
    listens there, and no wait will change that (a remote one may be slow, or come back)."""
    addresses = [tcp_address(e) for e in endpoints]
    if not addresses or any(a is None or not a[0].startswith(LOOPBACK) for a in addresses):
        return False
    for address in addresses:
        try:
            with socket.create_connection(address, timeout=0.5):  # type: ignore[arg-type]
                return False
        except ConnectionRefusedError:
            continue
        except OSError:
            return False
    return True

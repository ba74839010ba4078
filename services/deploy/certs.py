"""`voxshape certs DIR`: what a secured session needs, for development (the openssl command).

    voxshape certs deploy/secrets                       CA, router, one client per user
    voxshape certs deploy/secrets --host lab.example    the router's names, for TLS clients

Writes into DIR (kept when present, so a second run only adds what is missing):

- `ca.pem`, `ca.key`: a development certificate authority (keep ca.key private);
- `router.pem`, `router.key`: the router's TLS certificate, valid for localhost, 127.0.0.1,
  `router` (its compose service name) and every --host;
- `<user>.pem`, `<user>.key`: a client certificate per user of the access file (common name =
  user), for mutual TLS;
- `credentials`: `user:password` lines, a random password per user. The router reads it; a
  service given VOXSHAPE_SECRETS=DIR reads its own line. Give a remote teacher only its line.

Keys and credentials are readable by their owner only. A real deployment should use its own
CA; these are for development and tests.
"""

from __future__ import annotations

import argparse
import ipaddress
import os
import secrets
import shutil
import subprocess
from collections.abc import Iterable
from pathlib import Path

from services.deploy.access import AccessError, find_access_file, load_access, load_credentials
from services.runtime import ConfigError

DAYS = 825  # the longest validity clients commonly accept for a server certificate
ROUTER_NAMES = ("localhost", "127.0.0.1", "router")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("folder", type=Path, help="where to write them, e.g. deploy/secrets")
    parser.add_argument(
        "--host",
        action="append",
        default=[],
        help="another DNS name or IP of the router (repeatable)",
    )
    parser.add_argument(
        "--user",
        action="append",
        default=[],
        help="another user to make a certificate and password for (repeatable)",
    )
    parser.add_argument(
        "--access", type=Path, help="access file whose users get them (deploy/access.toml)"
    )


def _openssl(*argv: str) -> None:
    binary = shutil.which("openssl")
    if binary is None:
        raise ConfigError("the openssl command is missing: apt-get install openssl")
    result = subprocess.run([binary, *argv], capture_output=True, text=True, timeout=60)
    if result.returncode != 0:
        raise ConfigError(f"openssl {argv[0]} failed: {result.stderr.strip()}")


def _new_key(path: Path) -> None:
    _openssl(
        "genpkey", "-algorithm", "EC", "-pkeyopt", "ec_paramgen_curve:P-256", "-out", str(path)
    )
    path.chmod(0o600)


def make_ca(folder: Path) -> tuple[Path, Path]:
    cert, key = folder / "ca.pem", folder / "ca.key"
    if not cert.is_file():
        _new_key(key)
        _openssl(
            "req", "-x509", "-new", "-key", str(key), "-sha256", "-days", str(DAYS),
            "-subj", "/CN=voxshape development CA", "-out", str(cert),
            "-addext", "basicConstraints=critical,CA:TRUE",
            "-addext", "keyUsage=critical,keyCertSign,cRLSign",
        )  # fmt: skip
    return cert, key


def _alt_name(name: str) -> str:
    try:
        ipaddress.ip_address(name)
        return f"IP:{name}"
    except ValueError:
        return f"DNS:{name}"


def make_certificate(
    folder: Path, name: str, ca: tuple[Path, Path], *, server_names: Iterable[str] = ()
) -> tuple[Path, Path]:
    """`name`.pem/.key signed by the CA: a server's when `server_names` are given (its
    subject alternative names), else a client's with common name `name`."""
    cert, key = folder / f"{name}.pem", folder / f"{name}.key"
    if cert.is_file() and key.is_file():
        return cert, key
    request, extensions = folder / f"{name}.csr", folder / f"{name}.ext"
    _new_key(key)
    _openssl("req", "-new", "-key", str(key), "-subj", f"/CN={name}", "-out", str(request))
    names = list(dict.fromkeys(server_names))
    lines = ["basicConstraints=CA:FALSE", "keyUsage=critical,digitalSignature,keyEncipherment"]
    if names:
        lines += [
            "extendedKeyUsage=serverAuth",
            "subjectAltName=" + ",".join(map(_alt_name, names)),
        ]
    else:
        lines += ["extendedKeyUsage=clientAuth"]
    extensions.write_text("\n".join(lines) + "\n")
    try:
        _openssl(
            "x509", "-req", "-in", str(request), "-CA", str(ca[0]), "-CAkey", str(ca[1]),
            "-set_serial", str(secrets.randbits(63)), "-days", str(DAYS), "-sha256",
            "-extfile", str(extensions), "-out", str(cert),
        )  # fmt: skip
    finally:
        request.unlink(missing_ok=True)
        extensions.unlink(missing_ok=True)
    return cert, key


def add_credentials(path: Path, users: Iterable[str]) -> list[str]:
    """Adds a random password for each user not yet in the credentials file; returns them."""
    existing = load_credentials(path) if path.is_file() and path.read_text().strip() else {}
    added = [u for u in dict.fromkeys(users) if u not in existing]
    if added or not path.is_file():
        descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600)
        with os.fdopen(descriptor, "a") as f:
            f.writelines(f"{u}:{secrets.token_urlsafe(18)}\n" for u in added)
        path.chmod(0o600)
    return added


def make_all(folder: Path, users: Iterable[str], hosts: Iterable[str] = ()) -> dict[str, list[str]]:
    """Everything a secured session needs in `folder`; returns what was made."""
    folder.mkdir(parents=True, exist_ok=True)
    folder.chmod(0o700)
    ignore = folder / ".gitignore"
    if not ignore.exists():
        ignore.write_text("# secrets: never commit them\n*\n")
    before = {p.name for p in folder.iterdir()}
    ca = make_ca(folder)
    make_certificate(folder, "router", ca, server_names=(*ROUTER_NAMES, *hosts))
    users = list(dict.fromkeys(users))
    for user in users:
        make_certificate(folder, user, ca)
    added = add_credentials(folder / "credentials", users)
    made = sorted({p.name for p in folder.iterdir()} - before - {".gitignore"})
    return {"files": made, "passwords": added}


def run(args: argparse.Namespace) -> int:
    try:
        access = load_access(args.access or find_access_file())
    except AccessError as e:
        raise ConfigError(str(e)) from None
    made = make_all(args.folder, [*access, *args.user], args.host)
    print(f"{args.folder}: made {', '.join(made['files']) or 'nothing (all present)'}")
    if made["passwords"]:
        print(f"new passwords for: {', '.join(made['passwords'])} (in {args.folder}/credentials)")
    print(
        f"secure a session with VOXSHAPE_SECRETS={args.folder} (docker compose mounts "
        "deploy/secrets by default); keep ca.key and credentials private"
    )
    return 0

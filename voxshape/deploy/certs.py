"""`voxshape certs DIR`: what a secured session needs, for development (the openssl command).

    voxshape certs deploy/secrets                       CA, router, one client per user
    voxshape certs deploy/secrets --host lab.example    the router's names, for TLS clients

Writes into DIR (kept when present, so a second run only adds what is missing):

- `ca.pem`, `ca.key`: a development certificate authority (keep ca.key private);
- `router.pem`, `router.key`: the router's TLS certificate, valid for localhost, 127.0.0.1,
  `router` (its compose service name) and every --host;
- `<user>.pem`, `<user>.key`: a client certificate per user of the access file (common name =
  user), for mutual TLS;
- `page.pem`, `page.key`: the web page's HTTPS certificate (the same names and `web`);
- `credentials`: `user:password` lines, a random password per user. The router reads it; a
  service given VOXSHAPE_SECRETS=DIR reads its own line;
- `per-user/<user>/`: what that user needs and nothing else, for VOXSHAPE_SECRETS: its line of
  credentials, its certificate and key, ca.pem (and the web's page.pem/.key). The router's
  (`per-user/router/`) has every line: it checks them. Compose mounts each service's own; give
  a remote teacher its folder. No folder holds ca.key.

The CA may sign certificates for the session's names only (X.509 name constraints: localhost,
127.0.0.1, router, web and every --host), so a browser that trusts it trusts nothing else.
Keys and credentials are readable by their owner only. A real deployment should use its own
CA, and the page a certificate of the lab's (docs/web.md#https); these are for development and
tests.
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

from voxshape.deploy.access import AccessError, find_access_file, load_access, load_credentials
from voxshape.runtime import ConfigError

DAYS = 825  # the longest validity clients commonly accept for a server certificate
ROUTER_NAMES = ("localhost", "127.0.0.1", "router")
PAGE_NAMES = ("localhost", "127.0.0.1", "web")
PER_USER = "per-user"
CA_NAMES = "ca.names"  # the names the CA may sign for, one a line


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


def _subtree(name: str) -> str:
    try:
        address = ipaddress.ip_address(name)
    except ValueError:
        return f"permitted;DNS:{name}"
    mask = ipaddress.ip_network(f"{address}/{address.max_prefixlen}").netmask
    return f"permitted;IP:{address}/{mask}"


def make_ca(folder: Path, names: Iterable[str]) -> tuple[Path, Path]:
    """The CA, constrained to sign for `names` only; ConfigError if it exists already and was
    made for fewer (a new --host needs a new folder: the CA cannot grow)."""
    cert, key, listed = folder / "ca.pem", folder / "ca.key", folder / CA_NAMES
    names = list(dict.fromkeys(names))
    if cert.is_file():
        if listed.is_file():
            missing = set(names) - set(listed.read_text().split())
            if missing:
                raise ConfigError(
                    f"{folder}'s CA may sign for {', '.join(listed.read_text().split())} only, "
                    f"not {', '.join(sorted(missing))}: make the secrets again in a new folder "
                    "with every --host"
                )
        return cert, key
    _new_key(key)
    _openssl(
        "req", "-x509", "-new", "-key", str(key), "-sha256", "-days", str(DAYS),
        "-subj", "/CN=voxshape development CA", "-out", str(cert),
        "-addext", "basicConstraints=critical,CA:TRUE,pathlen:0",
        "-addext", "keyUsage=critical,keyCertSign,cRLSign",
        "-addext", "nameConstraints=critical," + ",".join(map(_subtree, names)),
    )  # fmt: skip
    listed.write_text("\n".join(names) + "\n")
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
    hosts = list(hosts)
    ca = make_ca(folder, (*ROUTER_NAMES, *PAGE_NAMES, *hosts))
    make_certificate(folder, "router", ca, server_names=(*ROUTER_NAMES, *hosts))
    make_certificate(folder, "page", ca, server_names=(*PAGE_NAMES, *hosts))
    users = list(dict.fromkeys(users))
    for user in users:
        make_certificate(folder, user, ca)
    added = add_credentials(folder / "credentials", users)
    make_per_user(folder, users)
    made = sorted({p.name for p in folder.iterdir()} - before - {".gitignore"})
    return {"files": made, "passwords": added}


def make_per_user(folder: Path, users: Iterable[str]) -> None:
    """`folder`/per-user/<name>/: one user's secrets only (the router's: every password)."""
    lines = (folder / "credentials").read_text().splitlines()
    own = {line.split(":", 1)[0]: line for line in lines if ":" in line}
    kits = {user: ([f"{user}.pem", f"{user}.key"], own[user] + "\n") for user in users}
    kits["router"] = (["router.pem", "router.key"], "\n".join(lines) + "\n")
    if "web" in kits:
        kits["web"][0].extend(["page.pem", "page.key"])
    for name, (files, credentials) in kits.items():
        kit = folder / PER_USER / name
        kit.mkdir(parents=True, exist_ok=True)
        kit.chmod(0o700)
        for file in ("ca.pem", *files):
            shutil.copyfile(folder / file, kit / file)
            (kit / file).chmod(0o644 if file.endswith(".pem") else 0o600)
        (kit / "credentials").write_text(credentials)
        (kit / "credentials").chmod(0o600)


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
        f"each service's {PER_USER}/<service> of deploy/secrets by default); give a remote "
        f"teacher its {args.folder}/{PER_USER}/<user>; keep ca.key and credentials private"
    )
    return 0

"""The session topology, read from compose.yaml: the one place that lists the services.

`voxshape up` runs the very commands compose.yaml gives each service. Only the variables
differ: compose reads them from the shell, the launcher from the shell over LOCAL_VARIABLES,
which put the router on loopback, and LOCAL_FOLDERS, which give local services the folders
(secrets, vosk model) that containers find mounted.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import yaml

LOCAL_VARIABLES = {
    "VOXSHAPE_ROUTER": "tcp/127.0.0.1:7447",  # where services connect
    "VOXSHAPE_ROUTER_LISTEN": "tcp/127.0.0.1:7447",  # where the router listens
    "VOXSHAPE_VIEWER_BIND": "127.0.0.1",  # the logger's live recording: this host only
    "VOXSHAPE_WEB_BIND": "127.0.0.1",  # the viewer profile's web viewer: this host only
    "VOXSHAPE_WEB_ADDRESS": "127.0.0.1",  # the teachers' web page: this host only
}
# Folders and files a container finds mounted at a fixed place; a local service gets the host's
# own (none by default: the local session is open, speech needs no vosk model, and the router
# and the web page find deploy/access.toml alike).
LOCAL_FOLDERS = {
    "VOXSHAPE_SERVICE_SECRETS": "VOXSHAPE_SECRETS",
    "VOXSHAPE_SERVICE_VOSK_MODEL": "VOXSHAPE_VOSK_MODEL",
    "VOXSHAPE_SERVICE_ACCESS": "VOXSHAPE_ACCESS",
}
RESTART_POLICIES = ("no", "always", "on-failure", "unless-stopped")
# A service labelled `voxshape.bus: "false"` announces no presence (the web viewer).
NOT_ON_BUS_LABEL = "voxshape.bus"


def local_variables(environ: Mapping[str, str] = os.environ) -> dict[str, str]:
    """The variables `voxshape up` interpolates compose.yaml with: LOCAL_VARIABLES and the
    local folders, overlaid by the environment."""
    folders = {inside: environ.get(host, "") for inside, host in LOCAL_FOLDERS.items()}
    return {**LOCAL_VARIABLES, **folders, **environ}


_VARIABLE = re.compile(r"\$(?:\$|\{(\w+)(?:(:?[-?])([^}]*))?\}|(\w+))")


class TopologyError(ValueError):
    """compose.yaml cannot be run; the message names the service and the problem."""


@dataclass(frozen=True)
class ServiceSpec:
    name: str
    command: tuple[str, ...]
    environment: dict[str, str]
    depends_on: tuple[str, ...]
    profiles: tuple[str, ...]
    on_bus: bool = True  # announces its presence (its node id) once it runs
    restart: str = "no"  # compose's restart policy: no, always, on-failure, unless-stopped

    @property
    def node(self) -> str:
        """The presence node id the service announces (its VOXSHAPE_NODE, else its name)."""
        return self.environment.get("VOXSHAPE_NODE", self.name)


def find_compose_file(start: Path | None = None) -> Path:
    """compose.yaml in the current directory or the project checkout this package runs from."""
    for folder in (start or Path.cwd(), Path(__file__).resolve().parents[2]):
        if (folder / "compose.yaml").is_file():
            return folder / "compose.yaml"
    raise TopologyError("no compose.yaml here or in the voxshape checkout; pass --compose PATH")


def interpolate(text: str, variables: Mapping[str, str], where: str) -> str:
    """Compose's variable syntax: $VAR, ${VAR}, ${VAR:-default}, ${VAR-default},
    ${VAR:?error}, ${VAR?error} and $$ for a literal $. Nesting is refused, not guessed."""
    if re.search(r"\$\{[^}]*\$\{", text):
        raise TopologyError(f"{where}: nested variables are not supported: {text!r}")

    def substitute(m: re.Match) -> str:
        if m.group(0) == "$$":
            return "$"
        name = m.group(1) or m.group(4)
        op, arg = m.group(2), m.group(3) or ""
        value = variables.get(name)
        unset = value is None or (op is not None and op.startswith(":") and value == "")
        if op in (":-", "-") and unset:
            return interpolate(arg, variables, where)
        if op in (":?", "?") and unset:
            raise TopologyError(f"{where}: variable {name} is required: {arg or 'set it'}")
        return value or ""

    return _VARIABLE.sub(substitute, text)


def load_topology(
    path: Path, variables: Mapping[str, str] | None = None, profiles: tuple[str, ...] = ()
) -> list[ServiceSpec]:
    """The services of compose.yaml that run without a profile or with one of `profiles`,
    dependencies first. Variables default to LOCAL_VARIABLES overlaid by the environment."""
    if variables is None:
        variables = local_variables()
    try:
        document = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as e:
        raise TopologyError(f"{path}: cannot read it: {e}") from None
    services = document.get("services") if isinstance(document, dict) else None
    if not isinstance(services, dict) or not services:
        raise TopologyError(f"{path}: has no `services:`")
    specs = {}
    for name, body in services.items():
        where = f"{path.name} service {name!r}"
        command = body.get("command")
        if not isinstance(command, list) or not all(isinstance(c, str) for c in command):
            raise TopologyError(f"{where}: `command` must be a list of strings (exec form)")
        environment = body.get("environment") or {}
        if not isinstance(environment, dict):
            raise TopologyError(f"{where}: `environment` must be a map")
        depends = body.get("depends_on") or []
        depends = list(depends) if isinstance(depends, dict | list) else []
        restart = str(body.get("restart", "no"))
        if restart not in RESTART_POLICIES:
            raise TopologyError(f"{where}: `restart` must be one of {', '.join(RESTART_POLICIES)}")
        specs[name] = ServiceSpec(
            name=name,
            command=tuple(interpolate(c, variables, where) for c in command),
            environment={
                str(k): interpolate(str(v), variables, where) for k, v in environment.items()
            },
            depends_on=tuple(depends),
            profiles=tuple(body.get("profiles") or ()),
            on_bus=str((body.get("labels") or {}).get(NOT_ON_BUS_LABEL, "true")) != "false",
            restart=restart,
        )
    chosen = {n: s for n, s in specs.items() if not s.profiles or set(s.profiles) & set(profiles)}
    return _dependencies_first(chosen, path)


def _dependencies_first(specs: dict[str, ServiceSpec], path: Path) -> list[ServiceSpec]:
    ordered: list[ServiceSpec] = []
    visiting: set[str] = set()

    def visit(name: str, chain: tuple[str, ...]) -> None:
        if any(s.name == name for s in ordered):
            return
        if name in visiting:
            raise TopologyError(f"{path.name}: dependency cycle {' -> '.join((*chain, name))}")
        if name not in specs:
            raise TopologyError(f"{path.name}: {chain[-1]!r} depends on unknown {name!r}")
        visiting.add(name)
        for dependency in specs[name].depends_on:
            visit(dependency, (*chain, name))
        ordered.append(specs[name])

    for name in specs:
        visit(name, ())
    return ordered

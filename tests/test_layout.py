"""The floors of docs/architecture.md#layout, checked from the imports: the shared floor
imports no service, and a service package imports only itself and the shared floor."""

from __future__ import annotations

import ast
from pathlib import Path

from tests.conftest import ROOT

SHARED = {"runtime", "world", "deploy", "recognition"}
SERVICES = {"arbiter", "learner", "logger", "sim", "speech", "teacher"}


def imports(path: Path) -> set[str]:
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    return found


def test_services_stand_on_the_shared_floor_only():
    services = ROOT / "services"
    wrong = []
    for package in sorted(SHARED | SERVICES):
        allowed = {package} | SHARED
        for path in sorted((services / package).rglob("*.py")):
            where = path.relative_to(services).as_posix()
            for module in sorted(imports(path)):
                parts = module.split(".")
                if parts[0] != "services" or len(parts) < 2:
                    continue
                if parts[1] not in allowed:
                    wrong.append(f"{where} imports {module}")
    assert not wrong, "\n".join(wrong)
    assert (services / "deploy").is_dir() and all((services / p).is_dir() for p in SERVICES)

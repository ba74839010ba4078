"""One way to start a session: only the launcher (voxshape/launcher/) spawns a router.

A session's router comes from compose.yaml through LocalSession (`voxshape up`, the demo) or
LoopbackSession (the benchmarks, the experiments, the test harnesses); a test of the router
itself (secured, meshed, killed) takes its command line from `router_command()`. Checked from
the AST of every .py file of the tree: no list, tuple or call's arguments outside the launcher
spell the command of `voxshape router` (or run `python -m voxshape.deploy.router`).
"""

from __future__ import annotations

import ast
from pathlib import Path

from tests.conftest import ROOT

LAUNCHER = ROOT / "voxshape" / "launcher"
TREE = ("protocol", "services", "benchmarks", "tests")


def _flat(elements: list[ast.expr]) -> list[ast.expr]:
    """The elements, a starred literal's own spliced in: [*(VOXSHAPE, "router"), ...]."""
    out: list[ast.expr] = []
    for e in elements:
        if isinstance(e, ast.Starred) and isinstance(e.value, ast.List | ast.Tuple):
            out += _flat(e.value.elts)
        else:
            out.append(e)
    return out


def _text(e: ast.expr | None) -> str | None:
    return e.value if isinstance(e, ast.Constant) and isinstance(e.value, str) else None


def _names_voxshape(e: ast.expr) -> bool:
    """VOXSHAPE, voxshape, "voxshape", "/path/to/voxshape", self.voxshape..."""
    if isinstance(e, ast.Name):
        return "voxshape" in e.id.lower()
    if isinstance(e, ast.Attribute):
        return "voxshape" in e.attr.lower()
    return (_text(e) or "").rsplit("/", 1)[-1] == "voxshape"


def _is_flag(e: ast.expr | None) -> bool:
    return (_text(e) or "").startswith("-")


def router_commands(source: str) -> list[int]:
    """The lines where `source` spells a router's command line: "router" after voxshape, or
    as a command (not a flag's value) followed by flags; "voxshape.deploy.router" after "-m"."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.List | ast.Tuple):
            elements = _flat(node.elts)
        elif isinstance(node, ast.Call):
            elements = _flat(node.args)
        else:
            continue
        for i, e in enumerate(elements):
            before = elements[i - 1] if i else None
            after = elements[i + 1] if i + 1 < len(elements) else None
            if (
                _text(e) == "router"
                and (
                    (before is not None and _names_voxshape(before))
                    or (_is_flag(after) and not _is_flag(before))
                )
            ) or (_text(e) == "voxshape.deploy.router" and _text(before) == "-m"):
                found.append(e.lineno)
    return sorted(set(found))


def _python_files() -> list[Path]:
    return sorted(p for top in TREE for p in (ROOT / top).rglob("*.py"))


def test_no_file_but_the_launcher_spawns_a_router():
    wrong = []
    for path in _python_files():
        if path.is_relative_to(LAUNCHER):
            continue
        for line in router_commands(path.read_text(encoding="utf-8")):
            wrong.append(f"{path.relative_to(ROOT)}:{line}")
    assert not wrong, (
        "a router spawned outside voxshape/launcher/ (a session: LoopbackSession; a test "
        "of the router itself: router_command()):\n" + "\n".join(wrong)
    )


def test_the_check_sees_the_launcher_s_own_router_command():
    found = [p for p in LAUNCHER.rglob("*.py") if router_commands(p.read_text(encoding="utf-8"))]
    assert [p.name for p in found] == ["session.py"]


def test_the_check_finds_each_way_a_router_was_spawned_by_hand():
    # each as it was written before the launcher was the one way (issue 49)
    spawned = [
        'Popen([voxshape, "router", "--session", session, "--listen", router])',
        'commands = [["router", "--session", bus.session, "--node", "router", "--listen", r]]',
        'self.start("router", "router", "--listen", self.router, bus=False)',
        'procs.start("router", "--session", session, "--node", "router", "--listen", router)',
        'spawn([*(VOXSHAPE, "router", "--session", s, "--node", "router"), *("--listen", e)])',
        'ServiceSpec("router", ("voxshape", "router"), env, (), ())',
        'pexpect.spawn(VOXSHAPE, ["router", "--secrets", str(secrets)], env=env)',
        'subprocess.Popen([sys.executable, "-m", "voxshape.deploy.router", "--listen", e])',
    ]
    for source in spawned:
        assert router_commands(source), source
    others = [
        'bus_config("router", env={})',
        'Node("router", bus)',
        '[VOXSHAPE, "sim", "--node", "router", "--listen", endpoint]',
        '{"mode": "router", "listen": {"endpoints": [endpoint]}}',
        'COMMANDS = {"router": ("run it", "voxshape.deploy.router", "add_arguments", "run")}',
    ]
    for source in others:
        assert not router_commands(source), source

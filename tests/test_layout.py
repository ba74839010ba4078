"""The floors of docs/architecture.md#layout, checked from the imports (absolute and relative):
voxshape.protocol imports nothing else of voxshape; voxshape.runtime only the protocol; the
shared floor (world, deploy, recognition, teaching) only itself, the runtime and the protocol;
each service (voxshape/services/<name>, one per process of compose.yaml) only itself and the
floors below; the top (the launcher, the lab, the command line) may import any of them."""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import ROOT

PACKAGE = ROOT / "voxshape"
SERVICES = PACKAGE / "services"
SHARED = {"world", "deploy", "recognition", "teaching"}
SERVICE_NAMES = {
    "arbiter", "learner", "logger", "ros2", "sim", "speech", "teacher", "web", "simteacher",
}  # fmt: skip
TOP = {"launcher", "lab"}  # put services together: may import any of them
TOP_MODULES = {"__init__", "__main__", "cli"}


def package_of(path: Path, root: Path = ROOT) -> list[str]:
    """The package a module's relative imports start from: `voxshape/services/speech/node.py`
    -> voxshape.services.speech, `voxshape/services/speech/__init__.py` -> the same."""
    parts = path.relative_to(root).with_suffix("").parts
    return list(parts[:-1])


def imports(path: Path, root: Path = ROOT) -> set[str]:
    return imported(path.read_text(encoding="utf-8"), package_of(path, root))


def imported(source: str, package: list[str]) -> set[str]:
    """The modules `source` imports, relative imports made absolute from `package` (`from .
    import mock` in voxshape/services/speech/node.py is voxshape.services.speech.mock)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            module = ".".join([*base, *([node.module] if node.module else [])])
            if node.level and not node.module:  # from . import a, b: each a module or a name
                found.update(f"{module}.{alias.name}" for alias in node.names)
            found.add(module)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    return found


def wrong_imports(folder: Path, allowed: set[str], root: Path = ROOT) -> list[str]:
    """`folder`'s imports of voxshape.X outside `allowed` (X names a package or module; a
    dotted X, such as services.sim, allows that subpackage alone)."""
    wrong = []
    for path in sorted(folder.rglob("*.py")):
        for module in sorted(imports(path, root)):
            parts = module.split(".")[1:] if module.startswith("voxshape.") else []
            if parts and not any(parts[: a.count(".") + 1] == a.split(".") for a in allowed):
                wrong.append(f"{path.relative_to(root)} imports {module}")
    return wrong


def floor_violations(root: Path = ROOT) -> list[str]:
    """Every import under root/voxshape that reaches above its floor: protocol < runtime <
    the shared floor < each service < the top."""
    package = root / "voxshape"
    below_services = {"protocol", "runtime"} | SHARED
    wrong = wrong_imports(package / "protocol", {"protocol"}, root)
    wrong += wrong_imports(package / "runtime", {"protocol", "runtime"}, root)
    for name in sorted(SHARED):
        wrong += wrong_imports(package / name, {name, "protocol", "runtime"}, root)
    for name in sorted(SERVICE_NAMES):
        allowed = below_services | {f"services.{name}"}
        wrong += wrong_imports(package / "services" / name, allowed, root)
    return wrong


def test_every_floor_imports_only_itself_and_the_floors_below():
    wrong = floor_violations()
    assert not wrong, "\n".join(wrong)


def test_every_package_and_module_is_on_a_floor():
    """A new package (or one left out, as ros2 once was) must be placed before it is checked."""
    packages = {p.parent.name for p in PACKAGE.glob("*/__init__.py")}
    assert packages == {"protocol", "runtime", "services"} | SHARED | TOP
    assert {p.parent.name for p in SERVICES.glob("*/__init__.py")} == SERVICE_NAMES
    assert {p.stem for p in SERVICES.glob("*.py")} == {"__init__"}
    assert {p.stem for p in PACKAGE.glob("*.py")} == TOP_MODULES


LAYOUT = ROOT / "docs" / "architecture.md"


def layout_entries(text: str) -> dict[str, set[str]]:
    """docs/architecture.md#layout's map: each folder under voxshape/ (an entry's first word)
    and the modules its entry names."""
    block = text.split("## Layout", 1)[1].split("```", 2)[1]
    entries: dict[str, set[str]] = {}
    folder = None
    for line in block.splitlines():
        if line[:1] not in ("", " "):  # a new entry: its folder first
            head = line.split()[0]
            folder = head if head.startswith("voxshape/") else None
            entries.setdefault(folder or "", set())
        if folder is not None:
            entries[folder].update(re.findall(r"(?<![/\w])(\w+)\.py\b", line))
    entries.pop("", None)
    return entries


def layout_mismatches(text: str, root: Path = ROOT) -> list[str]:
    """Modules of root/voxshape the map leaves out, and modules it names that are gone."""
    named = {f"{f}{m}.py" for f, modules in layout_entries(text).items() for m in modules}
    tree = {
        p.relative_to(root).as_posix()
        for p in (root / "voxshape").rglob("*.py")
        if p.name != "__init__.py"
    }
    return [f"not in the layout: {m}" for m in sorted(tree - named)] + [
        f"in the layout but gone: {m}" for m in sorted(named - tree)
    ]


def test_the_layout_names_every_module_of_the_tree():
    wrong = layout_mismatches(LAYOUT.read_text("utf-8"))
    assert not wrong, "\n".join(wrong)


@pytest.mark.parametrize(
    ("planted", "named", "wrong"),
    [
        ("world/maps.py", "", "not in the layout: voxshape/world/maps.py"),
        ("", "voxshape/world/  gone.py", "in the layout but gone: voxshape/world/gone.py"),
    ],
)
def test_a_module_left_out_of_the_layout_or_gone_is_caught(tmp_path, planted, named, wrong):
    (tmp_path / "voxshape" / "world").mkdir(parents=True)
    (tmp_path / "voxshape" / "world" / "robot.py").write_text("")
    if planted:
        (tmp_path / "voxshape" / planted).write_text("")
    text = f"## Layout\n\n```\nvoxshape/world/  robot.py (the robot)\n{named}\n```\n"
    assert layout_mismatches(text, tmp_path) == [wrong]


@pytest.mark.parametrize(
    ("where", "source"),
    [
        ("runtime/node.py", "from voxshape.teaching.joining import join"),
        ("world/maps.py", "from voxshape.services.sim.task import Simulation"),
        ("services/speech/node.py", "from voxshape.services.arbiter import config"),
        ("services/speech/node.py", "from ..arbiter import config"),
        ("protocol/keys.py", "import voxshape.runtime"),
        ("services/learner/sarsa.py", "from voxshape.lab.experiment import oracle"),
    ],
)
def test_an_import_above_its_floor_is_caught(tmp_path, where, source):
    """What the floors test finds in a tree with one import planted above its floor."""
    planted = tmp_path / "voxshape" / where
    planted.parent.mkdir(parents=True)
    planted.write_text(source + "\n")
    assert len(floor_violations(tmp_path)) == 1


def test_only_voxshape_is_installed_at_the_top_level(tmp_path):
    """Out of the source tree, the environment finds voxshape and none of the old top-level
    packages (a `services` or `protocol` of another project's would collide)."""
    probe = "import importlib.util as u; print([n for n in NAMES if u.find_spec(n)])"
    names = "NAMES = ('voxshape', 'services', 'protocol', 'lab', 'teaching'); "
    found = subprocess.run(
        [sys.executable, "-c", names + probe], cwd=tmp_path, capture_output=True, text=True,
        timeout=60, check=True, env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"},
    )  # fmt: skip
    assert found.stdout.strip() == "['voxshape']"


SPEECH = "voxshape/services/speech"


@pytest.mark.parametrize(
    ("where", "source", "module"),
    [
        (f"{SPEECH}/node.py", "from . import mock", "voxshape.services.speech.mock"),
        (f"{SPEECH}/node.py", "from .mock import X", "voxshape.services.speech.mock"),
        (f"{SPEECH}/node.py", "from ..arbiter import config", "voxshape.services.arbiter"),
        (f"{SPEECH}/__init__.py", "from .mock import X", "voxshape.services.speech.mock"),
        ("voxshape/lab/experiment/paper.py", "from ...services import sim", "voxshape.services"),
        ("voxshape/protocol/keys.py", "import voxshape.services.sim as n", "voxshape.services.sim"),
    ],
)
def test_relative_imports_are_read_as_the_modules_they_name(where, source, module):
    assert module in imported(source, package_of(ROOT / where))


# The functions of voxshape/protocol/keys.py that build a key of the bus.
KEY_BUILDERS = {
    "robot_key",
    "teacher_key",
    "presence_key",
    "session_keys",
    "message_key",
    "router_access_key",
}
# Where keys are built: the protocol (its key builders), the runtime (Node.subscribe,
# advertise, key), and voxshape/deploy, which writes the router's access rules from the same
# dataflow table.
BUILDS_KEYS = ("voxshape/protocol/", "voxshape/runtime/", "voxshape/deploy/")


def hand_built_keys(source: str) -> list[str]:
    """Where `source` builds a key of the bus: a call of a key builder, or a formatted string
    that starts with the keys' root (every key holds its session, so a literal one is none)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Call):
            name = getattr(node.func, "id", None) or getattr(node.func, "attr", None)
            if name in KEY_BUILDERS:
                found.append(f"line {node.lineno}: {name}(...)")
        elif isinstance(node, ast.JoinedStr) and node.values:
            first = node.values[0]
            text = first.value if isinstance(first, ast.Constant) else None
            root = (
                isinstance(first, ast.FormattedValue) and getattr(first.value, "id", "") == "ROOT"
            )
            if root or (isinstance(text, str) and text.startswith("voxshape/")):
                found.append(f"line {node.lineno}: f-string {ast.unparse(node)}")
    return found


def test_no_key_is_built_by_hand_outside_the_runtime():
    """A node names a topic and whose it is (Node.subscribe, advertise); the runtime builds
    the key and checks it against the node's row of voxshape/protocol/dataflow.py."""
    wrong = []
    for folder in ("voxshape", "benchmarks"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            where = path.relative_to(ROOT).as_posix()
            if not where.startswith(BUILDS_KEYS):
                wrong += [f"{where} {w}" for w in hand_built_keys(path.read_text("utf-8"))]
    assert not wrong, "\n".join(wrong)


@pytest.mark.parametrize(
    "source",
    [
        'node.input("obs", robot_key(node.session_id, "r1", "obs"))',
        "import protocol\nprotocol.teacher_key(s, t, 'notice')",
        'node.output("x", f"voxshape/{session}/robot/r1/obs")',
        'key = f"{ROOT}/{session}/**"',
    ],
)
def test_a_key_built_by_hand_is_caught(source):
    assert hand_built_keys(source)
    assert not hand_built_keys('node.subscribe("obs", "r1")\nENV_ID = "voxshape/Navigation-v0"')

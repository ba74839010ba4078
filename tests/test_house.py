"""The house's rules of size and naming (docs/architecture.md#layout), checked from the code's
syntax trees: no .py file over 500 lines and no function over 60 lines in voxshape/,
benchmarks/ or tests/, no top-level class name defined twice in voxshape/ or benchmarks/,
and no public module-level function or class name defined twice in voxshape/ (one name, one
idea) but the entry points every command's module has for the command line's table
(`add_arguments`, `run`)."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

from tests.conftest import ROOT

MAX_FILE_LINES = 500
MAX_FUNCTION_LINES = 60
SIZED = ("voxshape", "benchmarks", "tests")
NAMED = ("voxshape", "benchmarks")

# Known offenders, each with its reason; an entry that no longer offends fails the tests too,
# so that the lists only shrink.
FILES_ALLOWED_LONG: set[str] = set()
FUNCTIONS_ALLOWED_LONG: set[str] = set()
CLASSES_ALLOWED_TWICE: dict[str, set[str]] = {}
# Public names defined twice in voxshape/, with the files defining them.
NAMES_ALLOWED_TWICE: dict[str, set[str]] = {}


def sources(root: Path, folders: tuple[str, ...]) -> dict[str, ast.Module]:
    """Every .py file under `folders` of `root`, by its path relative to root, parsed."""
    found = {}
    for folder in folders:
        for path in sorted((root / folder).rglob("*.py")):
            found[path.relative_to(root).as_posix()] = ast.parse(path.read_text(encoding="utf-8"))
    return found


def long_files(root: Path) -> dict[str, int]:
    """The files over MAX_FILE_LINES lines, with their length."""
    lengths = {
        path: len((root / path).read_text(encoding="utf-8").splitlines())
        for path in sources(root, SIZED)
    }
    return {path: n for path, n in lengths.items() if n > MAX_FILE_LINES}


def long_functions(root: Path) -> dict[str, int]:
    """The functions and methods (nested ones too) over MAX_FUNCTION_LINES lines, from `def` to
    their last line, as path:name, with their length."""
    found = {}
    for path, tree in sources(root, SIZED).items():
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                length = node.end_lineno - node.lineno + 1
                if length > MAX_FUNCTION_LINES:
                    found[f"{path}:{node.name}"] = length
    return found


def classes_defined_twice(root: Path) -> dict[str, set[str]]:
    """The top-level class names defined in more than one place, with the files defining them."""
    where = defaultdict(list)
    for path, tree in sources(root, NAMED).items():
        for node in tree.body:
            if isinstance(node, ast.ClassDef):
                where[node.name].append(path)
    return {name: set(paths) for name, paths in where.items() if len(paths) > 1}


def command_entry_points(root: Path) -> set[tuple[str, str]]:
    """(name, path) of each function voxshape/cli.py's COMMANDS table names, in the file that
    defines it (a package's __init__.py that imports it names the module it comes from)."""
    cli = ast.parse((root / "voxshape" / "cli.py").read_text(encoding="utf-8"))
    table = next(
        node.value
        for node in cli.body
        if isinstance(node, ast.AnnAssign | ast.Assign) and "COMMANDS" in ast.unparse(node)
    )
    found = set()
    for _, module, *functions in ast.literal_eval(table).values():
        for name in functions:
            found.add((name, defined_in(root, module, name)))
    return found


def defined_in(root: Path, module: str, name: str) -> str:
    """The file (relative to root) that defines `name` for `module`: the module's own, or the
    one its `from X import name` names."""
    path = root / Path(*module.split("."))
    path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
    tree = ast.parse(path.read_text(encoding="utf-8"))
    imported = {
        alias.asname or alias.name: (node.module, alias.name)
        for node in tree.body
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0
        for alias in node.names
    }
    defined = {getattr(node, "name", None) for node in tree.body}
    if name in imported and name not in defined:
        return defined_in(root, *imported[name])
    return path.relative_to(root).as_posix()


def names_defined_twice(root: Path) -> dict[str, set[str]]:
    """The public module-level functions' and classes' names defined in more than one file of
    root/voxshape, but the commands' entry points, with the files defining them."""
    entry_points = command_entry_points(root)
    where = defaultdict(set)
    for path, tree in sources(root, ("voxshape",)).items():
        for node in tree.body:
            kinds = ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef
            public = isinstance(node, kinds) and not node.name.startswith("_")
            if public and (node.name, path) not in entry_points:
                where[node.name].add(path)
    return {name: paths for name, paths in where.items() if len(paths) > 1}


def unexpected(found: dict, allowed: dict | set, rule: str) -> list[str]:
    """What breaks `rule` without an allowance, then allowances no longer needed."""
    wrong = [f"{key}: {found[key]} ({rule})" for key in sorted(found) if key not in allowed]
    wrong += [
        f"{key} is allowed to break the rule '{rule}' but no longer does: remove it from the "
        "allowances in tests/test_house.py"
        for key in sorted(allowed)
        if key not in found
    ]
    return wrong


def test_no_file_is_over_500_lines():
    wrong = unexpected(long_files(ROOT), FILES_ALLOWED_LONG, f"at most {MAX_FILE_LINES} lines")
    assert not wrong, "split these into files of one purpose:\n" + "\n".join(wrong)


def test_no_function_is_over_60_lines():
    found = long_functions(ROOT)
    wrong = unexpected(found, FUNCTIONS_ALLOWED_LONG, f"at most {MAX_FUNCTION_LINES} lines")
    assert not wrong, "split these into functions a reader can hold:\n" + "\n".join(wrong)


def twice_against_allowed(found: dict, allowed: dict, table: str, kind: str, fix: str) -> list:
    """Names defined twice that `allowed` (the table named `table`) does not list, and names
    it lists that are no longer defined there twice."""
    wrong = [
        f"{kind}{name} in {', '.join(sorted(paths))}: {fix}"
        for name, paths in sorted(found.items())
        if allowed.get(name) != paths
    ]
    return wrong + [
        f"{kind}{name} is allowed in {', '.join(sorted(paths))} but no longer defined there "
        f"twice: remove it from {table} in tests/test_house.py"
        for name, paths in sorted(allowed.items())
        if found.get(name) != paths
    ]


def test_no_class_name_is_defined_twice():
    wrong = twice_against_allowed(
        classes_defined_twice(ROOT), CLASSES_ALLOWED_TWICE, "CLASSES_ALLOWED_TWICE", "class ",
        "give each a name that says what it is",
    )  # fmt: skip
    assert not wrong, "\n".join(wrong)


def test_no_public_name_is_defined_twice():
    wrong = twice_against_allowed(
        names_defined_twice(ROOT), NAMES_ALLOWED_TWICE, "NAMES_ALLOWED_TWICE", "",
        "name each by what it holds or does",
    )  # fmt: skip
    assert not wrong, "\n".join(wrong)


def test_a_name_defined_twice_is_caught(tmp_path):
    """Two public functions of one name are caught, a class too; a private one, a method and
    a command's entry point (named by the command line's table) are not."""
    package = tmp_path / "voxshape"
    (package / "a").mkdir(parents=True)
    (package / "b").mkdir()
    (package / "cli.py").write_text(
        'COMMANDS: dict = {"x": ("help", "voxshape.a", "add_arguments", "run"),\n'
        '                  "y": ("help", "voxshape.b", "add_arguments", "run")}\n'
    )
    (package / "a" / "__init__.py").write_text("from voxshape.a.command import run, add_arguments")
    body = "def add_arguments(p): ...\ndef run(a): ...\ndef _private(): ...\n"
    (package / "a" / "command.py").write_text(body + "def helper(): ...\nclass Thing: ...\n")
    (package / "b" / "__init__.py").write_text(
        body + "def helper(): ...\nclass Thing:\n    def helper(self): ...\n"
    )
    assert names_defined_twice(tmp_path) == {
        "helper": {"voxshape/a/command.py", "voxshape/b/__init__.py"},
        "Thing": {"voxshape/a/command.py", "voxshape/b/__init__.py"},
    }


def test_the_checks_see_what_they_check(tmp_path):
    """Each check finds its offence in a tree made to have it, and nothing in one without."""
    (tmp_path / "voxshape" / "a").mkdir(parents=True)
    (tmp_path / "benchmarks").mkdir()
    (tmp_path / "voxshape" / "protocol").mkdir()
    body = "".join(f"    x{i} = {i}\n" for i in range(MAX_FUNCTION_LINES - 1))
    fits, over = "def fits():\n" + body, "def over():\n" + body + "    y = 1\n"
    (tmp_path / "voxshape" / "a" / "long.py").write_text(
        "class Twice:\n    pass\n\n\n" + fits + "\n\n" + over
    )
    (tmp_path / "benchmarks" / "b.py").write_text("class Twice:\n    pass\n" + "\n" * 500)
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "test_t.py").write_text("\n" * 501 + over)
    protocol = tmp_path / "voxshape" / "protocol"
    (protocol / "c.py").write_text("class Once:\n    class Twice:\n        pass\n")
    assert long_files(tmp_path) == {"benchmarks/b.py": 502, "tests/test_t.py": 562}
    assert long_functions(tmp_path) == {
        "voxshape/a/long.py:over": MAX_FUNCTION_LINES + 1,
        "tests/test_t.py:over": MAX_FUNCTION_LINES + 1,
    }
    assert classes_defined_twice(tmp_path) == {
        "Twice": {"voxshape/a/long.py", "benchmarks/b.py"}  # the nested one is not top-level
    }

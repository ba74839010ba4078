"""The house's rules of size and naming (docs/architecture.md#layout), checked from the code's
syntax trees: no .py file over 500 lines and no function over 60 lines in voxshape/ or
benchmarks/, and no top-level class name defined twice in voxshape/ or benchmarks/ (one name,
one idea)."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

from tests.conftest import ROOT

MAX_FILE_LINES = 500
MAX_FUNCTION_LINES = 60
SIZED = ("voxshape", "benchmarks")
NAMED = ("voxshape", "benchmarks")

# Known offenders, each with its reason; an entry that no longer offends fails the tests too,
# so that the lists only shrink.
FILES_ALLOWED_LONG: set[str] = set()
FUNCTIONS_ALLOWED_LONG: set[str] = set()
CLASSES_ALLOWED_TWICE: dict[str, set[str]] = {}


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


def test_no_class_name_is_defined_twice():
    found = classes_defined_twice(ROOT)
    wrong = [
        f"class {name} in {', '.join(sorted(paths))}: give each a name that says what it is"
        for name, paths in sorted(found.items())
        if CLASSES_ALLOWED_TWICE.get(name) != paths
    ]
    wrong += [
        f"class {name} is allowed in {', '.join(sorted(paths))} but no longer defined there "
        "twice: remove it from CLASSES_ALLOWED_TWICE in tests/test_house.py"
        for name, paths in sorted(CLASSES_ALLOWED_TWICE.items())
        if found.get(name) != paths
    ]
    assert not wrong, "\n".join(wrong)


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
    protocol = tmp_path / "voxshape" / "protocol"
    (protocol / "c.py").write_text("class Once:\n    class Twice:\n        pass\n")
    assert long_files(tmp_path) == {"benchmarks/b.py": 502}
    assert long_functions(tmp_path) == {"voxshape/a/long.py:over": MAX_FUNCTION_LINES + 1}
    assert classes_defined_twice(tmp_path) == {
        "Twice": {"voxshape/a/long.py", "benchmarks/b.py"}  # the nested one is not top-level
    }

"""The reliability figures: runs the fault tests (tests/test_faults*.py) on a real bus and prints
the figures each printed, one fault per line (`--runs N` repeats them; `--json` for scripts).

    .venv/bin/python benchmarks/faults.py [--runs 3] [-k router]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MARK = "FAULT-FIGURES "


def run_once(select: str | None) -> tuple[int, list[dict]]:
    argv = [sys.executable, "-m", "pytest", "-q", "-s", "-p", "no:cacheprovider"]
    tests = sorted(str(p.relative_to(ROOT)) for p in (ROOT / "tests").glob("test_faults*.py"))
    argv += [*tests, *(["-k", select] if select else [])]
    result = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=900)
    found = [
        json.loads(line.removeprefix(MARK))
        for line in result.stdout.splitlines()
        if line.startswith(MARK)
    ]
    if result.returncode != 0:
        print(result.stdout[-3000:], file=sys.stderr)
    return result.returncode, found


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument("-k", dest="select", help="only the faults whose test matches")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    failed = 0
    for run in range(1, args.runs + 1):
        code, found = run_once(args.select)
        failed += code != 0
        for entry in found:
            if args.json:
                print(json.dumps({"run": run, **entry}))
            else:
                fault = entry.pop("fault")
                print(f"run {run} | {fault}: " + ", ".join(f"{k}={v}" for k, v in entry.items()))
    if failed:
        print(f"{failed} of {args.runs} runs had a failing fault test", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

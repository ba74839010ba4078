"""`python -m benchmarks.fleet`: the fleet's command (the package's docstring says what it
measures); also the harness's own browser processes (`--browser-client`)."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import tempfile
from pathlib import Path
from typing import Any

from benchmarks.fleet import __doc__ as what
from benchmarks.fleet.clients import browser_client
from benchmarks.fleet.measure import measure, results
from benchmarks.fleet.profiling import Profiler, find_py_spy
from benchmarks.fleet.report import plot, print_report
from benchmarks.fleet.session import Fleet
from voxshape.services.sim.world import MAX_ROBOTS
from voxshape.services.speech.mock import MockSettings


# -- the command ----------------------------------------------------------------------------------
def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=(what or "").splitlines()[0])
    parser.add_argument("--robots", default="1,5,10,20", help="N values (default 1,5,10,20)")
    parser.add_argument("--teachers", default="1,10,40", help="M values (default 1,10,40)")
    parser.add_argument(
        "--points", help="NxM pairs instead of every N with every M, e.g. 1x1,5x10,20x40"
    )
    parser.add_argument("--seconds", type=float, default=30.0, help="the window of each point")
    parser.add_argument("--warmup", type=float, default=5.0, help="seconds before the window")
    parser.add_argument(
        "--browsers",
        type=int,
        help="browser teachers among the M (default: M - M // 2; the rest simulated people)",
    )
    parser.add_argument(
        "--word-every", type=float, default=15.0, help="a browser's mean seconds between words"
    )
    parser.add_argument(
        "--robots-per-sim",
        type=int,
        help=f"robots a simulator process (default {MAX_ROBOTS}, all a world holds: "
        "beyond, several simulators)",
    )
    parser.add_argument(
        "--mock-latency",
        type=float,
        default=MockSettings().latency_s,
        help="seconds the mock engine takes to hear a simulated person (0: the session's own "
        "latency alone)",
    )
    parser.add_argument("--plot", type=Path, help="draw the points' figures to this PNG")
    parser.add_argument("--task", default="1")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="one JSON object per point")
    parser.add_argument("--profile-seconds", type=float, default=10.0, help="0: no profile")
    parser.add_argument("--py-spy", help="the py-spy to use (default: on PATH, else cProfile)")
    parser.add_argument("--workdir", type=Path, help="default: a new temporary directory")
    # the harness's own browser processes
    parser.add_argument("--browser-client", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--url", help=argparse.SUPPRESS)
    parser.add_argument("--assign", help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    return parser


def points_of(args: argparse.Namespace) -> list[tuple[int, int]]:
    if args.points:
        pairs = [p.lower().split("x") for p in args.points.split(",") if p.strip()]
        return [(int(n), int(m)) for n, m in pairs]
    return [(int(n), int(m)) for n in args.robots.split(",") for m in args.teachers.split(",")]


def say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def main() -> int:
    args = _parser().parse_args()
    if args.browser_client:
        return browser_client(args)
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="voxshape-fleet-"))
    # SIGTERM, or SIGINT (which a background job ignores): the points so far, children ended
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    py_spy = find_py_spy(args.py_spy)
    todo = points_of(args)
    profiler = Profiler(args.profile_seconds, workdir, py_spy)
    say(f"fleet: {len(todo)} points in {workdir}; py-spy: {py_spy or 'not installed'}")
    done, failed = run_points(todo, args, workdir, profiler)
    profiler.add_equivalent(done, args.task)
    (workdir / "points.jsonl").write_text("".join(json.dumps(p) + "\n" for p in done + failed))
    if args.json:
        for point in done + failed:
            print(json.dumps(point, sort_keys=True))
    else:
        print_report(done, failed)
    if args.plot and done:
        plot(done, args.plot)
    return 0 if len(done) == len(todo) else 1


# -- the points -----------------------------------------------------------------------------------
def run_points(
    todo: list[tuple[int, int]], args: argparse.Namespace, workdir: Path, profiler: Profiler
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Each point in turn, until Ctrl-C or SIGTERM: the points measured, the points failed."""
    done: list[dict[str, Any]] = []
    failed: list[dict[str, Any]] = []
    try:
        for i, (n, m) in enumerate(todo):
            profiler.index, profiler.last = len(done), i == len(todo) - 1
            try:
                point = run_point(n, m, args, workdir, profiler)
            except RuntimeError as e:  # a service died, or did not start: said, and go on
                say(f"  failed: {e}")
                failed.append({"robots": n, "teachers": m, "error": str(e)[:2000]})
                continue
            done.append(point)
            say(f"  {point['limit']['what']}; {', '.join(point['limit']['symptoms']) or 'on time'}")
    except KeyboardInterrupt:
        say("stopped early: the points so far")
    return done, failed


def run_point(
    n: int, m: int, args: argparse.Namespace, workdir: Path, profile_now: Any
) -> dict[str, Any]:
    """One session: start, warm up, measure, maybe profile, stop; its figures."""
    robots = tuple(f"r{i + 1}" for i in range(n))
    browsers = min(m, args.browsers) if args.browsers is not None else m - m // 2
    fleet = Fleet(workdir / f"{n}x{m}", robots, m - browsers, browsers, args)
    say(f"{n} robots, {m} teachers ({m - browsers} simulated, {browsers} browsers): starting")
    try:
        took = fleet.start()
        say(f"  ready in {took:.0f} s; warm-up {args.warmup:g} s, window {args.seconds:g} s")
        reading, _, t0, t1 = measure(fleet, args)
        pids = fleet.pids()
        point = results(fleet, reading, t0, t1, [])  # a first verdict, to choose a profile
        profile = profile_now(point, pids)
        fleet.stop()
        point = results(fleet, reading, t0, t1, fleet.browser_records())
        point["started_in_s"] = round(took, 1)
        point["service_counters"] = fleet.service_counters()
        if profile:
            point["profile"] = profile
        return point
    finally:
        fleet.stop()


if __name__ == "__main__":
    sys.exit(main())

"""A class teaches a fleet: N robots at real time (10 Hz) and M teachers in one session, measured.

    .venv/bin/python benchmarks/fleet.py --points 1x1,5x10,10x10,20x40 --seconds 30
    .venv/bin/python benchmarks/fleet.py --robots 1,5,10,20 --teachers 1,10,40 --json

Each point (N robots, M teachers; `--robots` x `--teachers`, or the pairs of `--points`) is a
session of its own, on loopback, with its own session id and free ports: a router, ONE
simulator process for the N robots (`voxshape sim --robot r1 --robot r2 ...`; a world holds
28 robots, so past 28 one simulator for each 28, `--robots-per-sim`), ONE learner process
serving all N, the arbiter, the speech service with the mock engine and the web page's
gateway (`voxshape web`). The M teachers are spread over the robots (teacher i teaches robot
i mod N): half of them, rounded down, are simulated people (`voxshape sim-teacher`, its default
profile: at most 4 words a robot minute, at salient moments), the others browsers
(`--browsers` sets their number): WebSocket clients of the page that speak its own protocol
(services/teacher/web/static/net.js and app.js): log in, five clock probes 100 ms apart and one
every 30 s, `watch` their robot, read every map frame the gateway sends (all robots' at up to
10 Hz each), and press one of the page's word buttons every `--word-every` seconds on average
(exponential gaps). The browsers run in processes of the harness, at most 10 in each.

Measured over `--seconds` after `--warmup` (all wall clock, one machine):

- CPU (percent of one core) and resident memory of every process, psutil; the whole
  machine's busy share, so other work on it shows;
- each robot's achieved step rate against 10 Hz, from its observations on the bus (steps
  advanced over the simulator's wall time), the share of steps it took without a fresh
  action (none newer than the simulator's 0.5 s: it stood still), and observation -> the
  learner's action;
- a word's latency: said -> understood notice -> credited feedback, p50/p99, matched by
  utterance id (a simulated person: said = its `Said` left it, understood = the arbiter's
  notice on the bus; a browser: said = the `say` frame was sent, understood = the page got
  the notice; feedback = the learner's feedback on the bus naming the utterance);
- the page's frames: a map frame's age when it reaches the browser (now - the simulator's
  wall time of that observation), and frames a browser got a second;
- words lost: said within the window (bar its last 3 s) and never understood.

It names the first resource to run out (a process at 85% of a core or more, or the
machine's cores), and profiles the limiting process of the first point where something ran
out (else of the last point): py-spy `--gil` on the live process if it is installed
(`--py-spy`, else on PATH), else cProfile of an in-process equivalent (simulator, learner,
arbiter or gateway), else none. Every process it starts is ended by pid, on Ctrl-C and on
failure too.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.fleet_clients import browser_client
from benchmarks.fleet_measure import measure, results
from benchmarks.fleet_profile import equivalent_profile, find_py_spy, py_spy_profile
from benchmarks.fleet_session import MAX_ROBOTS_PER_SIM, Fleet
from services.speech.mock import MockSettings


# -- the command ----------------------------------------------------------------------------------
def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
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
        help=f"robots a simulator process (default {MAX_ROBOTS_PER_SIM}, all a world holds: "
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


def plot(points: list[dict], path: Path) -> None:
    """The capacity curve: the slowest robot's rate, the machine's load and the word and frame
    latencies against robots (one line per number of teachers)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = (
        ("min_robot_rate_hz", "slowest robot, Hz"),
        ("busy_percent", "machine busy, % of one core"),
        ("word_to_feedback_p99_ms", "word said -> feedback p99, ms"),
        ("frame_age_p99_ms", "page frame age p99, ms"),
    )
    fig, axes = plt.subplots(1, len(panels), figsize=(4 * len(panels), 3.2))
    for ax, (key, label) in zip(axes, panels, strict=True):
        for m in sorted({p["teachers"] for p in points}):
            mine = sorted(
                (p["robots"], p["machine"][key] if key == "busy_percent" else p.get(key))
                for p in points
                if p["teachers"] == m
            )
            xs = [x for x, y in mine if y is not None]
            ax.plot(xs, [y for _, y in mine if y is not None], marker="o", label=f"{m} teachers")
        ax.set_xlabel("robots")
        ax.set_title(label, fontsize=9)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


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
        fleet.kill_all()


class Profiler:
    """Profiles the limiting process of the first point where something ran out (or of the
    last point): py-spy on the live process; with no py-spy, noted for an in-process
    profile at the end. `index` and `last`: the point being measured."""

    def __init__(self, seconds: float, workdir: Path, py_spy: str | None) -> None:
        self.seconds, self.workdir, self.py_spy = seconds, workdir, py_spy
        self.index, self.last = 0, False  # where the point will be among those measured
        self.profiled = False
        self.equivalent: tuple[str, int] | None = None  # (process, index) for the end

    def __call__(self, point: dict[str, Any], pids: dict[str, int]) -> str | None:
        """py-spy on the limiting process, of the first point where something ran out (or
        the last point); with no py-spy, noted for an in-process profile at the end."""
        if self.profiled or self.seconds <= 0 or not (point["limit"]["ran_out"] or self.last):
            return None
        self.profiled = True
        process = point["limit"]["process"]
        pid = pids.get(process)
        if self.py_spy is None or pid is None:
            self.equivalent = (process, self.index)
            return None
        say(f"  py-spy on {process} (pid {pid}) for {self.seconds:g} s")
        out = self.workdir / f"py-spy-{process}.txt"
        return f"{process}: " + py_spy_profile(self.py_spy, pid, self.seconds, out)

    def add_equivalent(self, done: list[dict[str, Any]], task: str) -> None:
        """The in-process profile noted, into its point."""
        if self.equivalent is None:
            return
        process, index = self.equivalent
        text = equivalent_profile(process, done[index], task) if index < len(done) else None
        done[index]["profile"] = text or f"{process}: no profile available for it"


# -- the report ---------------------------------------------------------------------------------
def print_report(done: list[dict[str, Any]], failed: list[dict[str, Any]]) -> None:
    """The tables, the failed points, what ran out first and the profile."""
    print(markdown(done) if done else "no point measured")
    for f in failed:
        print(f"\n{f['robots']} robots, {f['teachers']} teachers failed: {f['error'][-600:]}")
    first = next((p for p in done if p["limit"]["ran_out"]), None)
    print()
    if first:
        print(
            f"first to run out: {first['limit']['what']} at {first['robots']} robots, "
            f"{first['teachers']} teachers ({', '.join(first['limit']['symptoms'])})"
        )
    else:
        print("nothing ran out at these points")
    for p in done:
        if "profile" in p:
            print(f"\nprofile at {p['robots']} robots, {p['teachers']} teachers:\n")
            print("```\n" + p["profile"] + "\n```")


def _ms(v: float | None) -> str:
    return "-" if v is None else f"{v:.0f}"


def _pair(words: dict[str, Any], what: str) -> str:
    return f"{_ms(words[what + '_p50_ms'])} / {_ms(words[what + '_p99_ms'])}"


def markdown(points: list[dict[str, Any]]) -> str:
    lines = _points_table(points)
    lines += ["", "CPU, % of one core (RSS, MB):", ""]
    lines += _cpu_table(points)
    return "\n".join(lines)


def _points_table(points: list[dict[str, Any]]) -> list[str]:
    lines = [
        "| robots | teachers (simulated + browsers) | slowest robot, Hz (steps without a fresh "
        "action) | obs -> action p50 / p99 ms | words said / lost "
        "| browser: said -> understood p50 / p99 ms | browser: said -> feedback "
        "| simulated: said -> understood | simulated: said -> feedback "
        "| page frame age p50 / p99 ms | frames a browser got / s (sent) | limit |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for p in points:
        sims = f" ({p['simulators']} simulators)" if p["simulators"] > 1 else ""
        b, m = p["words_by_teacher_kind"]["browser"], p["words_by_teacher_kind"]["sim"]
        frames = (
            "-"
            if p["frames_per_browser_s"] is None
            else f"{p['frames_per_browser_s']:.0f} ({p['frames_expected_per_browser_s']:.0f})"
        )
        lines.append(
            f"| {p['robots']}{sims} | {p['teachers']} ({p['sim_teachers']} + {p['browsers']}) "
            f"| {p['min_robot_rate_hz']:.2f} ({p['steps_without_action_share']:.0%}) "
            f"| {_ms(p['obs_to_action_p50_ms'])} / "
            f"{_ms(p['obs_to_action_p99_ms'])} | {p['words_said']} / {p['words_lost']} "
            f"| {_pair(b, 'to_notice')} | {_pair(b, 'to_feedback')} "
            f"| {_pair(m, 'to_notice')} | {_pair(m, 'to_feedback')} "
            f"| {_ms(p['frame_age_p50_ms'])} / {_ms(p['frame_age_p99_ms'])} | {frames} "
            f"| {p['limit']['what']} |"
        )
    return lines


def _cpu_table(points: list[dict[str, Any]]) -> list[str]:
    names = sorted({k for p in points for k in p["cpu_percent"]}, key=_process_order)
    lines = ["| robots x teachers | " + " | ".join(names) + " | machine busy (others) |"]
    lines.append("|---|" + "---|" * (len(names) + 1))
    for p in points:
        cells = [
            f"{p['cpu_percent'][n]:.0f} ({p['rss_mb'][n]:.0f})" if n in p["cpu_percent"] else "-"
            for n in names
        ]
        m = p["machine"]
        lines.append(
            f"| {p['robots']} x {p['teachers']} | "
            + " | ".join(cells)
            + f" | {m['busy_percent']:.0f} of {100 * m['cores']} ({m['others_percent']:.0f}) |"
        )
    return lines


def _process_order(name: str) -> tuple[int, str]:
    order = ["sim", "learner", "arbiter", "speech", "web", "router", "sim-teachers"]
    return (order.index(name), name) if name in order else (len(order), name)


if __name__ == "__main__":
    sys.exit(main())

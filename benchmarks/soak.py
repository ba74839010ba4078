"""The soak: four robots and four simulated teachers at real time for an hour (`--minutes`),
no faults. Prints (and writes to `--out`) each service's resident memory (VmRSS) at the start,
after 10 minutes and at the end, the latencies at the start and at the end, and the sizes of
the event log and the recording, so growth can be judged.

    .venv/bin/python benchmarks/soak.py --minutes 60 --out soak.md

Latencies, as a bus node of the harness sees them (wall clock, the same machine):
utterance -> the arbiter's notice about it; utterance -> the feedback credited from it (the
arbiter waits for late words of other teachers first, so this includes its merge window);
observation -> the learner's action for that step. "start": the first `--window` minutes
after warm-up; "end": the last `--window` minutes.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.harness import Session
from benchmarks.probe import Probe

WARM_UP_S = 60.0  # memory "at start" is taken after a minute: imports, first episodes done
Sample = tuple[float, dict[str, int], dict[str, int]]  # seconds, memory (kB), sizes (bytes)


def main() -> int:
    args = _parser().parse_args()
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="voxshape-soak-"))
    robots = tuple(f"r{i + 1}" for i in range(args.robots))
    session = Session(workdir, robots, args.rtf, session_id="soak", seed=args.seed)
    samples: list[Sample] = []
    print(f"soak: {len(robots)} robots at {args.rtf:g}x for {args.minutes:g} min in {workdir}")
    # stopped early (SIGTERM, or SIGINT, which a background job ignores): the tables so far
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    probe = Probe(session.client_config("probe"), keep_obs=4000)
    session.start()
    probe.start()
    t0 = time.monotonic()
    args.t0_wall = time.time()
    try:
        _sample_until_done(samples, probe, session, args, t0)
        samples.append(_sample(session, time.monotonic() - t0))
    except KeyboardInterrupt:
        print("stopped early: the tables so far", file=sys.stderr)
        samples.append(_sample(session, time.monotonic() - t0))
    finally:
        probe.stop()
        code, counters, teachers = session.stop()
        session.kill_all()
    text = _publish(samples, probe, session, args, final=True)
    extra = _counters(code, counters, teachers)
    text += "\n```\n" + json.dumps(extra, indent=1, sort_keys=True) + "\n```\n"
    if args.out:
        args.out.write_text(text)
    print(text)
    return 0 if code == 0 else 1


def _parser() -> argparse.ArgumentParser:
    """The command line, as the module's docstring shows it."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--robots", type=int, default=4)
    parser.add_argument("--rtf", type=float, default=1.0)
    parser.add_argument("--window", type=float, default=5.0, help="minutes of latency samples")
    parser.add_argument("--sample-every", type=float, default=60.0, help="seconds")
    parser.add_argument("--out", type=Path, help="write the tables here too (rewritten as it goes)")
    parser.add_argument("--workdir", type=Path, help="default: a new temporary directory")
    parser.add_argument("--seed", type=int, default=0)
    return parser


def _sample_until_done(
    samples: list[Sample], probe: Probe, session: Session, args: argparse.Namespace, t0: float
) -> None:
    """A sample every `--sample-every` seconds after the warm-up, the tables rewritten with
    each, until `--minutes` have passed or the session stops by itself."""
    total = args.minutes * 60
    next_sample = WARM_UP_S
    while True:
        elapsed = time.monotonic() - t0
        if session.up is not None and session.up.poll() is not None:
            print("the session stopped by itself", file=sys.stderr)
            return
        if elapsed >= next_sample or elapsed >= total:
            samples.append(_sample(session, elapsed))
            _publish(samples, probe, session, args)
            next_sample += args.sample_every
        if elapsed >= total:
            return
        time.sleep(min(1.0, max(0.05, min(next_sample, total) - elapsed)))


def _sample(session: Session, elapsed: float) -> Sample:
    """The services' memory and the sizes of the event log and the recording, now."""
    sizes = {
        name: (session.run_dir / name).stat().st_size
        for name in ("events.msgpack", "recording.rrd")
        if (session.run_dir / name).exists()
    }
    return elapsed, session.memory(), sizes


def _publish(
    samples: list[Sample],
    probe: Probe,
    session: Session,
    args: argparse.Namespace,
    final: bool = False,
) -> str:
    """The tables so far, written to `--out` too."""
    text = report(samples, probe, session, args, final)
    if args.out:
        args.out.write_text(text)
    return text


def _counters(code: int | None, counters: dict[str, dict], teachers: dict[str, dict]) -> dict:
    """The launcher's exit code, each service's messages missed for good, what each teacher
    said and the notices it got."""
    return {
        "launcher_exit": code,
        "missed": {
            s: {k: v for k, v in c.items() if k.startswith("missed.")} for s, c in counters.items()
        },
        "teachers": {
            r: {k: v for k, v in c.items() if "said" in k or "notice" in k}
            for r, c in teachers.items()
        },
    }


def report(
    samples: list[Sample], probe: Probe, session: Session, args: argparse.Namespace, final: bool
) -> str:
    """The tables so far (rewritten at each sample)."""
    if not samples:
        return "no sample yet\n"
    first = samples[0]
    ten = next((s for s in samples if s[0] >= 600), None)
    last = samples[-1]
    services = sorted(set(first[1]) | set(last[1]))
    lines = [
        f"# soak: {len(session.robots)} robots, {args.rtf:g}x, "
        f"{last[0] / 60:.1f} of {args.minutes:g} min{' (final)' if final else ''}",
        "",
        "| process | RSS at start (MB) | after 10 min | at the end | growth after 10 min |",
        "|---|---|---|---|---|",
    ]
    for s in services:
        a, b, c = first[1].get(s, 0), (ten[1].get(s, 0) if ten else None), last[1].get(s, 0)
        grow = f"{(c - b) / 1024:+.1f}" if b else "-"
        lines.append(
            f"| {s} | {a / 1024:.1f} | {'-' if b is None else f'{b / 1024:.1f}'} | "
            f"{c / 1024:.1f} | {grow} |"
        )
    lines += ["", "| file | size at start (MB) | after 10 min | at the end | MB per hour |"]
    lines.append("|---|---|---|---|---|")
    for name in sorted(last[2]):
        a, c = first[2].get(name, 0), last[2][name]
        b = ten[2].get(name) if ten else None
        rate = (c - a) / max(1.0, last[0] - first[0]) * 3600 / 1e6
        lines.append(
            f"| {name} | {a / 1e6:.1f} | {'-' if b is None else f'{b / 1e6:.1f}'} | "
            f"{c / 1e6:.1f} | {rate:.0f} |"
        )
    now, t0_wall = time.time(), args.t0_wall
    window = args.window * 60
    start = probe.latencies(t0_wall + WARM_UP_S, t0_wall + WARM_UP_S + window)
    end = probe.latencies(now - window, now)
    lines += ["", "| latency (ms) | start p50 | start p95 | end p50 | end p95 | n start / end |"]
    lines.append("|---|---|---|---|---|---|")
    for name in ("utterance_to_notice_ms", "utterance_to_feedback_ms", "obs_to_action_ms"):
        lines.append(
            f"| {name.removesuffix('_ms').replace('_', ' ')} | {start[name + '.p50']} | "
            f"{start[name + '.p95']} | {end[name + '.p50']} | {end[name + '.p95']} | "
            f"{start[name + '.n']} / {end[name + '.n']} |"
        )
    lines += ["", "memory samples (minute: service=MB):"]
    for t, mem, _ in samples:
        lines.append(
            f"- {t / 60:5.1f}: " + ", ".join(f"{k}={v / 1024:.0f}" for k, v in sorted(mem.items()))
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())

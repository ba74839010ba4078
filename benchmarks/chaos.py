"""The chaos run: a whole session (`voxshape up` with the mock speech engine and the logger, two
robots, a simulated teacher each) paced at 10x for `--minutes`, while a seeded monkey kills
(SIGKILL) or freezes (SIGSTOP for 15 s, then SIGCONT) a random service every 20-40 s, the
router included. Then it checks, from the event log, the learners' checkpoints and the
services' counters, that every word the arbiter understood reached its learner exactly once,
that every learner converged, that the event log reads to its end and that a replay shows what
the live recording shows; and prints the tables (benchmarks/harness is the harness).

    .venv/bin/python benchmarks/chaos.py [--minutes 10] [--seed 1] [--out chaos.md]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.harness import (
    LearnerLoss,
    Monkey,
    Verdict,
    fault_table,
    random_schedule,
    run_chaos,
    verdict_table,
)


def main() -> int:
    args = _parser().parse_args()
    robots = tuple(args.robots.split(","))
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="voxshape-chaos-"))
    seconds = args.minutes * 60
    schedule = random_schedule(args.seed, seconds)
    print(
        f"chaos: {len(schedule)} faults over {args.minutes:g} min, seed {args.seed}, in {workdir}"
    )
    t0 = time.monotonic()
    monkey, verdict, losses, extra = run_chaos(
        workdir, robots, args.rtf, seconds, schedule, seed=args.seed
    )
    took = (time.monotonic() - t0) / 60
    text = _tables(args, robots, took, monkey, verdict, losses)
    print(text)
    if args.out:
        args.out.write_text(text)
        args.out.with_suffix(".json").write_text(_details(verdict, extra))
    return 0 if verdict.ok else 1


def _parser() -> argparse.ArgumentParser:
    """The command line, as the module's docstring shows it."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="wall minutes of faults")
    parser.add_argument("--seed", type=int, default=1, help="the monkey's (and teachers') seed")
    parser.add_argument("--rtf", type=float, default=10.0)
    parser.add_argument("--robots", default="r1,r2")
    parser.add_argument("--out", type=Path, help="write the tables here too")
    parser.add_argument("--workdir", type=Path, help="default: a new temporary directory")
    return parser


def _tables(
    args: argparse.Namespace,
    robots: tuple[str, ...],
    took: float,
    monkey: Monkey,
    verdict: Verdict,
    losses: list[LearnerLoss],
) -> str:
    """The faults injected, the verdict per robot, and the checks of the log and the replay."""
    lost = "; ".join(
        f"{x.robot} checkpoint {x.checkpoint_age_s:.1f} s old, {x.steps_lost} steps" for x in losses
    )
    lines = [
        f"# chaos: {args.minutes:g} min at {args.rtf:g}x, robots {args.robots}, seed {args.seed}"
        f" ({took:.1f} wall minutes in all)",
        "",
        fault_table(monkey),
        "",
        verdict_table(verdict, robots),
        "",
        f"- event log: {verdict.log_records} records, {verdict.log_tail or 'read to its end'}",
        f"- replay vs live recording: {'equal' if verdict.replay_equal else 'DIFFERENT'} "
        f"({verdict.replay_note})",
        f"- missed for good (missed.*, last counters): {verdict.missed or 'none'}",
        f"- learning lost per learner kill: {lost or 'no learner kill'}",
        f"- problems: {'; '.join(verdict.problems) or 'none'}",
    ]
    return "\n".join(lines) + "\n"


def _details(verdict: Verdict, extra: dict) -> str:
    """The words lost and duplicated, and the services' exit codes and last counters, as JSON."""
    return json.dumps(
        {
            "lost": verdict.lost,
            "duplicated": verdict.duplicated,
            "exit": extra["exit"],
            "counters": extra["counters"],
            "teachers": extra["teachers"],
        },
        indent=1,
        default=str,
    )


if __name__ == "__main__":
    sys.exit(main())

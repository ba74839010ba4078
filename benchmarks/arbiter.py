"""Credit accuracy of the arbiter's core (no bus): a scripted teacher with a given reaction
delay, delay jitter and clock skew judges a 10 Hz robot (services/arbiter/scripted.py); the
table gives the share of judgements credited within one step of the step they reacted to,
with the delay learnt (once it is) and with TAMER's fixed 0.2-0.8 s window, and the median
error in steps. Seeds are averaged.

    .venv/bin/python benchmarks/arbiter.py [--seeds 3] [--steps 3000]
"""

from __future__ import annotations

import argparse
import statistics

from services.arbiter.scripted import ScriptedTeacher, rehearse

DELAYS = (0.0, 0.5, 1.0, 1.5, 1.7, 2.0)
SKEWS = (-5.0, 0.0, 5.0)
JITTERS = (0.0, 0.1, 0.2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--steps", type=int, default=3000)
    args = parser.parse_args()
    print(
        "| delay s | jitter s | skew s | learnt: within 1 step | median error (steps) "
        "| judgements before learnt | TAMER 0.2-0.8 s: within 1 step |"
    )
    print("|---|---|---|---|---|---|---|")
    for jitter in JITTERS:
        for delay in DELAYS:
            for skew in SKEWS:
                learnt, errors, before, tamer = [], [], [], []
                for seed in range(args.seeds):
                    teacher = ScriptedTeacher(delay=delay, skew=skew, jitter=jitter)
                    run = rehearse(teacher, steps=args.steps, seed=seed)
                    fixed = rehearse(teacher, steps=args.steps, seed=seed, learn=False)
                    learnt.append(run.within_one_step())
                    errors.append(run.median_error())
                    before.append(run.learned_after if run.learned_after is not None else -1)
                    tamer.append(fixed.within_one_step(after_learning=False))
                print(
                    f"| {delay:g} | {jitter:g} | {skew:+g} | {statistics.mean(learnt):.3f} "
                    f"| {statistics.median(errors):+.2f} | {statistics.median(before):g} "
                    f"| {statistics.mean(tamer):.3f} |"
                )


if __name__ == "__main__":
    main()

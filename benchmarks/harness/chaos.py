"""A whole chaos session: started, hit by the monkey on a schedule, left to settle, stopped and
judged; and the learning each learner kill lost.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from benchmarks.harness.monkey import Fault, Monkey
from benchmarks.harness.session import Session
from benchmarks.harness.verdict import Verdict, checkpoint_meta, verify
from benchmarks.probe import Probe


@dataclass
class LearnerLoss:
    robot: str
    checkpoint_age_s: float  # how old its checkpoint was when the learner was killed
    steps_lost: int  # the robot's latest step then, minus the checkpoint's


def learner_losses(session: Session, probe: Probe) -> list[LearnerLoss]:
    """Just before a learner is killed: per robot, what its checkpoint lacks."""
    out = []
    now = time.time()
    with probe.lock:
        latest: dict[str, int] = {}
        for robot, step in probe.seen.obs_at:
            latest[robot] = max(step, latest.get(robot, -1))
    for robot in session.robots:
        path = session.run_dir / f"learner-{robot}.npz"
        try:
            age = now - path.stat().st_mtime
            step = int(checkpoint_meta(path)["step"])
        except (OSError, KeyError, ValueError):
            continue
        out.append(LearnerLoss(robot, round(age, 2), latest.get(robot, step) - step))
    return out


def run_chaos(
    workdir: Path,
    robots: tuple[str, ...],
    rtf: float,
    seconds: float,
    schedule: list[Fault],
    seed: int = 0,
    settle: float = 20.0,
    convergence: bool = True,
    say: Callable[[str], None] = print,
) -> tuple[Monkey, Verdict, list[LearnerLoss], dict]:
    """A whole chaos session: starts it, injects `schedule`, lets the last words settle,
    stops it and judges it. Returns the monkey, the verdict, the learning lost per learner
    kill and figures (launcher exit code, counters)."""
    session = Session(workdir, robots, rtf, seed=seed)
    probe = Probe(session.client_config("probe"))
    monkey = Monkey(session, say)
    losses: list[LearnerLoss] = []
    monkey.before_kill = lambda service: losses.extend(
        learner_losses(session, probe) if service == "learner" else []
    )
    try:
        session.start()
        probe.start()
        monkey.run(schedule, seconds)
        time.sleep(settle)  # the last words reach the learners; restarted ones catch up
        probe.stop()
        code, counters, teachers = session.stop()
        verdict = verify(session, probe, counters, teachers, convergence_needed=convergence)
    finally:
        session.kill_all()
    if code != 0:
        verdict.problems.append(f"voxshape up exited with {code}")
    for i in monkey.injected:
        if not i.ok:
            verdict.problems.append(f"{i.fault.kind} {i.fault.service}: {i.note}")
    return monkey, verdict, losses, {"exit": code, "counters": counters, "teachers": teachers}

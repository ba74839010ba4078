"""`voxshape experiment distributed`: one task and setting run twice for the same seeds, once
in-process (voxshape/lab/experiment/inprocess.py) and once with every service as its own process
over zenoh: a router, the simulator on the lockstep clock, the learner, and for the feedback
settings the arbiter, the mock speech service and the simulated teacher. Same seeds, same
learning results expected (within noise: the bus delivers a teacher's words at wall-clock
moments, not at the in-process run's exact steps), and the wall time of both.

The bus run is made the in-process one's equal where it can be: the teacher keeps to robot
time (the arbiter takes it as a robot-time teacher: its delays and rate are per robot second,
at lockstep's ~50 robot seconds a wall second), its errors are split as in-process (its own
slips, the mock engine's mishearings), the mock hears at once (its latency is wall time), and
the learner replays the very traces the in-process run dictates.

The session is a LoopbackSession (voxshape/launcher/loopback.py): compose.yaml's router and
services on a free loopback port, each process logging to its own file, ended by pid.
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from voxshape.lab.experiment.inprocess import ROBOT, SETTINGS, TEACHER, RunSpec, initial_traces, run
from voxshape.lab.experiment.intervals import mean_ci
from voxshape.launcher import LoopbackSession
from voxshape.launcher.topology import ServiceSpec
from voxshape.protocol import EpisodeEvent, TeacherNotice
from voxshape.runtime import Input, Node
from voxshape.runtime.settings_file import RUNS, read_settings
from voxshape.services.learner.config import LearnerConfig
from voxshape.services.learner.convergence import Convergence, EpisodeResult, convergence_on
from voxshape.services.sim.task import SimConfig
from voxshape.services.simteacher.teacher import Confusion
from voxshape.world.maps import load_map

ACTION_WAIT_S = 30.0  # lockstep: the simulator waits this long for the learner
PERIOD = SimConfig().control_period


@dataclass(frozen=True)
class LearningOutcome:
    """How one run learnt: the figures compared between the two ways of running it."""

    converged: bool
    episodes: int
    learning_time_s: float
    durations_s: list[float]
    wall_time_s: float
    interventions: int  # understood utterances until convergence (or the end)


def in_process(spec: RunSpec) -> LearningOutcome:
    start = time.monotonic()
    result = run(spec)
    return LearningOutcome(
        result.converged,
        result.episodes,
        result.learning_time_s,
        result.durations_s[: result.episodes],
        round(time.monotonic() - start, 1),
        result.interventions,
    )


def over_zenoh(spec: RunSpec, timeout_s: float = 1800.0) -> LearningOutcome:
    """The same run with every service as its own process; the simulator's episode events
    tell when it converged (the rule of voxshape/services/learner/convergence.py)."""
    with tempfile.TemporaryDirectory(prefix="voxshape-equivalence-") as folder:
        where = Path(folder)
        start = time.monotonic()
        with LoopbackSession(f"equivalence-{os.getpid()}", logs=where, cwd=where) as session:
            progress, interventions = _follow(spec, session, where, start + timeout_s)
    return LearningOutcome(
        progress.converged,
        progress.n_episodes,
        round(progress.learning_time, 1),
        [e.sim_seconds for e in progress.episodes[: progress.n_episodes]],
        round(time.monotonic() - start, 1),
        interventions,
    )


def _services(spec: RunSpec, session: LoopbackSession, folder: Path) -> list[ServiceSpec]:
    """The teacher's services in a feedback setting, then the learner, replaying the
    in-process run's traces (the simulator is apart: it starts last)."""
    services = _teacher_services(spec, session) if SETTINGS[spec.setting].feedback else []
    learner = ["--robot", ROBOT, "--task", spec.task, "--fresh", "--seed", str(spec.seed)]
    learner += [a for setting in spec.learner for a in ("--set", setting)]
    learner += ["--checkpoint", str(folder / "learner.npz")]
    if dictation := initial_traces(spec):  # the in-process run's traces, replayed alike
        dictation.book.save(folder / "traces.npz")
        learner += ["--traces", str(folder / "traces.npz")]
    return [*services, session.service("learner", *learner)]


def _teacher_services(spec: RunSpec, session: LoopbackSession) -> list[ServiceSpec]:
    """The arbiter, the mock speech service and the simulated teacher, erring as in-process."""
    seed = ["--seed", str(spec.seed)]
    slips, misheard = noise_shares(SETTINGS[spec.setting].noise)
    teacher = ["--teacher", TEACHER, "--task", spec.task, "--noise", str(slips)]
    # The mock's recognition latency is wall seconds: 0 here, where 0.3 s would be 100+
    # lockstep steps (the in-process run's recognition is 0.3 robot seconds, 3 steps).
    speech = ["--engine", "mock", "--latency", "0", *seed]
    speech += ["--error-rate", str(misheard), "--confusion", "misheard=1,dropped=0,inserted=0"]
    sim_teacher = ["voxshape", "sim-teacher", "--robot", ROBOT, *teacher, *seed]
    return [
        session.service("arbiter", "--robot-time", TEACHER),
        session.service("speech", *speech),
        session.client("sim-teacher", sim_teacher),
    ]


def _simulator(spec: RunSpec, session: LoopbackSession) -> ServiceSpec:
    """The simulator on the lockstep clock, waiting ACTION_WAIT_S at most for each answer."""
    sim = ["--task", spec.task, "--clock", "lockstep", "--robot", ROBOT, "--seed", str(spec.seed)]
    return session.service("sim", *sim, "--action-timeout", str(ACTION_WAIT_S))


def _follow(
    spec: RunSpec, session: LoopbackSession, folder: Path, deadline: float
) -> tuple[Convergence, int]:
    """Starts the services, the simulator last, and follows the run to convergence or its
    episode limit: its progress and interventions."""
    with Node("equivalence", session.client_config("equivalence")) as node:
        node.subscribe("episode", ROBOT)
        node.subscribe("notice", TEACHER)
        session.add(*_services(spec, session, folder))
        time.sleep(0.5)  # their subscriptions reach the router with their tokens
        # The simulator starts last, once the others are present: in lockstep it waits for an
        # answer to each observation (ACTION_WAIT_S at most), so none may miss the first one.
        session.add(_simulator(spec, session))
        # judged with the settings the learner ran with, as it recorded them
        run = folder / RUNS / session.session_id  # the services run in `folder`
        learner = read_settings(run, "learner", LearnerConfig)
        if learner is None:
            raise RuntimeError(f"the learner recorded no settings in {run}")
        progress = convergence_on(load_map(spec.task), learner)
        return progress, _watch(node, session, progress, spec.max_episodes, deadline)


def noise_shares(noise: float) -> tuple[float, float]:
    """The in-process teacher's error rate split as over the bus: its own slips (the opposite
    qualifier, said by the sim-teacher) and mishearings (made by the mock speech engine), in
    the proportions of the profile's Confusion."""
    c = Confusion()
    share = c.wrong_qualifier / (c.wrong_qualifier + c.misheard)
    return noise * share, noise * (1 - share)


def _watch(
    node: Node,
    session: LoopbackSession,
    progress: Convergence,
    max_episodes: int,
    deadline: float,
) -> int:
    """Follows the episodes until convergence or `max_episodes`; returns the interventions
    meanwhile (the teacher's words the arbiter understood, as its notices say: its
    TeachingStats are sent at most once a wall second, many episodes apart in lockstep).
    A service that dies ends it (ServiceDied, naming it)."""
    interventions = 0
    while len(progress.episodes) < max_episodes and not progress.converged:
        if time.monotonic() > deadline:
            raise TimeoutError(f"no convergence nor {max_episodes} episodes in time")
        session.check_children()
        event = node.poll(0.5)
        if isinstance(event, Input) and isinstance(event.message, EpisodeEvent):
            e = event.message
            if e.kind != "start":
                progress.add(EpisodeResult(e.kind, e.episode_steps, e.episode_steps * PERIOD))
        elif isinstance(event, Input) and isinstance(event.message, TeacherNotice):
            interventions += event.message.kind == "understood"
    return interventions


def compare(spec: RunSpec, seeds: list[int]) -> dict:
    """Both ways for each seed: their outcomes, whether the learning matched exactly, and the
    means of both ways (within noise of each other, when not identical)."""
    runs = []
    for seed in seeds:
        one = replace(spec, seed=seed)
        local, bus = in_process(one), over_zenoh(one)
        same = local.durations_s == bus.durations_s
        runs.append(
            {"seed": seed, "in_process": asdict(local), "over_zenoh": asdict(bus), "same": same}
        )
    return {
        "task": spec.task,
        "setting": spec.setting,
        "max_episodes": spec.max_episodes,
        "runs": runs,
        "summary": {way: _summary([r[way] for r in runs]) for way in WAYS},
        "identical": sum(r["same"] for r in runs),
    }


WAYS = ("in_process", "over_zenoh")


def _summary(outcomes: list[dict]) -> dict:
    minutes, half = mean_ci(o["learning_time_s"] / 60 for o in outcomes)
    return {
        "learning_time_min": round(minutes, 2),
        "learning_time_min_ci95": round(half, 2),
        "episodes": statistics.fmean(o["episodes"] for o in outcomes),
        "interventions": statistics.fmean(o["interventions"] for o in outcomes),
        "converged_fraction": statistics.fmean(o["converged"] for o in outcomes),
        "wall_time_s": round(sum(o["wall_time_s"] for o in outcomes), 1),
    }


def comparison_markdown(comparison: dict) -> str:
    """A Markdown table of a comparison, and its means."""
    lines = [
        f"Task {comparison['task']}, setting `{comparison['setting']}`: in-process vs every "
        "service its own process over zenoh (lockstep)",
        "",
        "| seed | episodes (in-process / zenoh) | learning time min | interventions | converged "
        "| same episodes | wall s |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in comparison["runs"]:
        a, b = r["in_process"], r["over_zenoh"]
        lines.append(
            f"| {r['seed']} | {a['episodes']} / {b['episodes']} "
            f"| {a['learning_time_s'] / 60:.1f} / {b['learning_time_s'] / 60:.1f} "
            f"| {a['interventions']} / {b['interventions']} "
            f"| {a['converged']} / {b['converged']} | {'yes' if r['same'] else 'no'} "
            f"| {a['wall_time_s']:.0f} / {b['wall_time_s']:.0f} |"
        )
    a, b = (comparison["summary"][way] for way in WAYS)
    n = len(comparison["runs"])
    lines += [
        f"| mean | {a['episodes']:.1f} / {b['episodes']:.1f} "
        f"| {a['learning_time_min']:.1f} ± {a['learning_time_min_ci95']:.1f} / "
        f"{b['learning_time_min']:.1f} ± {b['learning_time_min_ci95']:.1f} "
        f"| {a['interventions']:.0f} / {b['interventions']:.0f} "
        f"| {a['converged_fraction']:.0%} / {b['converged_fraction']:.0%} "
        f"| {comparison['identical']} of {n} | {a['wall_time_s']:.0f} / {b['wall_time_s']:.0f} |",
        "",
        f"Learning time (robot minutes, mean ± 95% interval): {a['learning_time_min']:.2f} ± "
        f"{a['learning_time_min_ci95']:.2f} in-process, {b['learning_time_min']:.2f} ± "
        f"{b['learning_time_min_ci95']:.2f} over zenoh; {comparison['identical']} of {n} runs "
        f"learnt step for step the same episodes. Over zenoh took "
        f"{b['wall_time_s'] / max(a['wall_time_s'], 0.1):.1f}x the wall time "
        f"({b['wall_time_s']:.0f} s against {a['wall_time_s']:.0f} s, every process started "
        "and stopped for each run).",
    ]
    return "\n".join(lines)

"""`voxshape experiment distributed`: one task and setting run twice for the same seeds, once
in-process (services/experiment/inprocess.py) and once with every service as its own process
over zenoh: a router, the simulator on the lockstep clock, the learner, and for the feedback
settings the arbiter, the mock speech service and the simulated teacher. Same seeds, same
learning results expected (within noise: the bus delivers a teacher's words at wall-clock
moments, not at the in-process run's exact steps), and the wall time of both.

The bus run is made the in-process one's equal where it can be: the teacher keeps to robot
time (the arbiter takes it as a robot-time teacher: its delays and rate are per robot second,
at lockstep's ~50 robot seconds a wall second), its errors are split as in-process (its own
slips, the mock engine's mishearings), the mock hears at once (its latency is wall time), and
the learner replays the very traces the in-process run dictates.

Processes are started and stopped here, by pid, on a free loopback port.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from protocol import EpisodeEvent, TeacherNotice, robot_key, teacher_key
from services.experiment.inprocess import ROBOT, SETTINGS, TEACHER, RunSpec, initial_traces, run
from services.experiment.intervals import mean_ci
from services.learner.config import LearnerConfig
from services.learner.convergence import Convergence, EpisodeResult, convergence_on
from services.runtime import Input, Node, Presence, bus_config, free_loopback_port
from services.runtime.processes import end_process
from services.sim.task import SimConfig
from services.teacher.simulated.teacher import Confusion
from services.world.maps import load_map

VOXSHAPE = [sys.executable, "-m", "services"]
STOP_WAIT_S = 10.0
JOIN_WAIT_S = 60.0
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


@dataclass(frozen=True)
class _Bus:
    """The session the services join, through a router listening on a loopback port."""

    session: str
    router: str

    def join(self, node: str) -> list[str]:
        """A service's arguments to join the session as `node`."""
        where = ["--session", self.session, "--node", node]
        return [*where, "--mode", "client", "--connect", self.router]


def over_zenoh(spec: RunSpec, timeout_s: float = 1800.0) -> LearningOutcome:
    """The same run with every service as its own process; the simulator's episode events
    tell when it converged (the rule of services/learner/convergence.py)."""
    bus = _Bus(f"equivalence-{os.getpid()}", f"tcp/127.0.0.1:{free_loopback_port()}")
    with tempfile.TemporaryDirectory(prefix="voxshape-equivalence-") as folder:
        commands = _service_commands(spec, bus, folder)
        children: list[subprocess.Popen] = []
        start = time.monotonic()
        try:
            progress, interventions = _follow(
                spec, bus, commands, folder, children, start + timeout_s
            )
        finally:
            for child in reversed(children):
                _stop(child)
    return LearningOutcome(
        progress.converged,
        progress.n_episodes,
        round(progress.learning_time, 1),
        [e.sim_seconds for e in progress.episodes[: progress.n_episodes]],
        round(time.monotonic() - start, 1),
        interventions,
    )


def _service_commands(spec: RunSpec, bus: _Bus, folder: str) -> list[list[str]]:
    """The router first, the teacher's services in a feedback setting, then the learner,
    replaying the in-process run's traces (the simulator is apart: it starts last)."""
    commands = [["router", "--session", bus.session, "--node", "router", "--listen", bus.router]]
    if SETTINGS[spec.setting].feedback:
        commands += _teacher_commands(spec, bus)
    checkpoint = str(Path(folder) / "learner.npz")
    learner = [
        "learner",
        *bus.join("learner"),
        "--robot",
        ROBOT,
        "--fresh",
        "--seed",
        str(spec.seed),
    ]
    commands.append([*learner, "--checkpoint", checkpoint])
    if book := initial_traces(spec):  # the in-process run's traces, replayed alike
        book.save(Path(folder) / "traces.npz")
        commands[-1] += ["--traces", str(Path(folder) / "traces.npz")]
    return commands


def _teacher_commands(spec: RunSpec, bus: _Bus) -> list[list[str]]:
    """The arbiter, the mock speech service and the simulated teacher, erring as in-process."""
    seed = ["--seed", str(spec.seed)]
    slips, misheard = noise_shares(SETTINGS[spec.setting].noise)
    teacher = ["--teacher", TEACHER, "--task", spec.task, "--noise", str(slips)]
    # The mock's recognition latency is wall seconds: 0 here, where 0.3 s would be 100+
    # lockstep steps (the in-process run's recognition is 0.3 robot seconds, 3 steps).
    speech = ["--engine", "mock", "--latency", "0", *seed]
    speech += ["--error-rate", str(misheard), "--confusion", "misheard=1,dropped=0,inserted=0"]
    return [
        ["arbiter", *bus.join("arbiter"), "--robot-time", TEACHER],
        ["speech", *bus.join("speech"), *speech],
        ["sim-teacher", *bus.join("sim-teacher"), "--robot", ROBOT, *teacher, *seed],
    ]


def _sim_command(spec: RunSpec, bus: _Bus) -> list[str]:
    """The simulator on the lockstep clock, waiting ACTION_WAIT_S at most for each answer."""
    sim = ["sim", *bus.join("sim"), "--task", spec.task, "--clock", "lockstep", "--robot", ROBOT]
    return [*sim, "--seed", str(spec.seed), "--action-timeout", str(ACTION_WAIT_S)]


def _follow(
    spec: RunSpec,
    bus: _Bus,
    commands: list[list[str]],
    folder: str,
    children: list[subprocess.Popen],
    deadline: float,
) -> tuple[Convergence, int]:
    """Starts the services into `children` (the caller stops them), the simulator last, and
    follows the run to convergence or its episode limit: its progress and interventions."""
    children.append(_start(commands[0], folder))
    time.sleep(1.0)  # the router listens before the others connect
    config = replace(bus_config("equivalence"), session=bus.session, mode="client")
    with Node("equivalence", replace(config, connect=(bus.router,))) as node:
        node.input("episode", robot_key(bus.session, ROBOT, "episode"))
        node.input("notice", teacher_key(bus.session, TEACHER, "notice"))
        node.watch_presence()
        children.extend(_start(c, folder) for c in commands[1:])
        _await(node, {c[0] for c in commands[1:]}, time.monotonic() + JOIN_WAIT_S)
        time.sleep(0.5)  # their subscriptions reach the router with their tokens
        # The simulator starts last, once the others are present: in lockstep it waits for an
        # answer to each observation (ACTION_WAIT_S at most), so none may miss the first one.
        children.append(_start(_sim_command(spec, bus), folder))
        progress = convergence_on(load_map(spec.task), LearnerConfig())
        return progress, _watch(node, progress, spec.max_episodes, deadline, children)


def noise_shares(noise: float) -> tuple[float, float]:
    """The in-process teacher's error rate split as over the bus: its own slips (the opposite
    qualifier, said by the sim-teacher) and mishearings (made by the mock speech engine), in
    the proportions of the profile's Confusion."""
    c = Confusion()
    share = c.wrong_qualifier / (c.wrong_qualifier + c.misheard)
    return noise * share, noise * (1 - share)


def _watch(
    node: Node,
    progress: Convergence,
    max_episodes: int,
    deadline: float,
    children: list[subprocess.Popen],
) -> int:
    """Follows the episodes until convergence or `max_episodes`; returns the interventions
    meanwhile (the teacher's words the arbiter understood, as its notices say: its
    TeachingStats are sent at most once a wall second, many episodes apart in lockstep)."""
    interventions = 0
    while len(progress.episodes) < max_episodes and not progress.converged:
        if time.monotonic() > deadline:
            raise TimeoutError(f"no convergence nor {max_episodes} episodes in time")
        if dead := [c for c in children if c.poll() is not None]:
            raise RuntimeError(f"a service died: {' '.join(map(str, dead[0].args[2:4]))}")
        event = node.poll(0.5)
        if isinstance(event, Input) and isinstance(event.message, EpisodeEvent):
            e = event.message
            if e.kind != "start":
                progress.add(EpisodeResult(e.kind, e.episode_steps, e.episode_steps * PERIOD))
        elif isinstance(event, Input) and isinstance(event.message, TeacherNotice):
            interventions += event.message.kind == "understood"
    return interventions


def _await(node: Node, names: set[str], deadline: float) -> None:
    missing = set(names)
    while missing and time.monotonic() < deadline:
        event = node.poll(0.2)
        if isinstance(event, Presence) and event.alive:
            missing.discard(event.node)
    if missing:
        raise TimeoutError(f"{', '.join(sorted(missing))} did not join the session")


def _start(command: list[str], folder: str) -> subprocess.Popen:
    log = open(Path(folder) / f"{command[0]}.log", "w")  # noqa: SIM115 (closed with the folder)
    return subprocess.Popen([*VOXSHAPE, *command], stdout=log, stderr=log, cwd=folder)


def _stop(child: subprocess.Popen) -> None:
    end_process(child, STOP_WAIT_S, STOP_WAIT_S)


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


def report(comparison: dict) -> str:
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

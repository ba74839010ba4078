"""`voxshape demo`: the main job on the embedded default (a local session, no docker).

Starts the session of compose.yaml (router, logger, simulator, learner, speech, arbiter), each
service its own process, plus a simulated teacher that speaks: synthesized audio through the speech
service's default engine (voxshape/services/speech/cascade.py) when espeak-ng and sox are installed,
else text through the mock speech engine. It trains the task of VOXSHAPE_TASK (task 1 by default, or
a map file) until the learner converges (voxshape/services/learner/convergence.py, judged by that
map's shortest time), showing each episode, then stops the session and writes the logger's
recording, the report's pictures (voxshape/lab/report/) and a table of the episodes under
runs/<session>/: demo.md counts episodes and interventions from the event log as the report's
summary.md does.

`voxshape demo --web` is a session a person teaches in a browser instead: it also starts the
web page of compose.yaml (docs/web.md), prints its address, runs no simulated teacher unless
`--sim-teacher`, and the robot runs at real time unless `--rtf`.

The simulator runs paced at `--rtf` times real time: the arbiter credits what teachers say by
the wall-clock display time of the steps, so the robot must not outrun that (a lockstep
simulator here runs ~500 steps/s, and 0.1 s of a teacher's timing would cover 50 steps). The
simulated teacher's delays are robot seconds, and the arbiter is told so (VOXSHAPE_ROBOT_TIME).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from dataclasses import replace
from pathlib import Path

from voxshape import launcher
from voxshape.lab.closing import Alone, WordCount, closing_lines
from voxshape.lab.experiment.inprocess import RunSpec
from voxshape.lab.experiment.inprocess import run as run_experiment
from voxshape.lab.progress import FINAL_WAIT_S, ConvergenceWatch, StallWatch
from voxshape.lab.report import load_run, write_report
from voxshape.lab.report.counts import INTERVENTIONS_ARE, EpisodeCounts
from voxshape.lab.report.summary import RobotSummary
from voxshape.launcher.topology import ServiceSpec
from voxshape.protocol import EpisodeEvent, LearningSummary, Said, TeachingStats
from voxshape.runtime import BusError, Input, Tick
from voxshape.services.learner.config import with_settings
from voxshape.services.learner.convergence import convergence_on
from voxshape.services.logger.run import RUNS, RunDir, RunError
from voxshape.services.simteacher.teacher import PROFILES
from voxshape.services.speech.recognizer import DEFAULT_ENGINE
from voxshape.world.maps import Map, load_map

ROBOT, TEACHER = "r1", "simteacher"
TASK = "1"  # the default task


def add_arguments(parser: argparse.ArgumentParser) -> None:
    # --task, --rtf, --robots as `voxshape up`'s, with the demo's defaults
    launcher.add_arguments(parser, {"task": TASK, "robots": ROBOT})
    parser.set_defaults(rtf=None)  # 10, or 1 with --web: a person teaches at real time
    rtf = parser._option_string_actions["--rtf"]
    rtf.help = "simulated seconds per wall second, paced (VOXSHAPE_RTF; default 10; --web: 1)"
    parser.add_argument(
        "--web",
        action="store_true",
        help="teach it yourself in a browser: serves the web page (its address is printed) "
        "and runs no simulated teacher unless --sim-teacher; the robot runs at real time "
        "unless --rtf. It has no time limit: once the robot has learnt, the page says so and "
        "the robot goes on, episode after episode, until you end it (Ctrl-C)",
    )
    parser.add_argument(
        "--sim-teacher",
        action="store_true",
        help="with --web: the simulated teacher teaches too",
    )
    parser.add_argument(
        "--max-episodes",
        type=int,
        default=60,
        help="give up if not converged by then (default 60; not with --web, which its person ends)",
    )
    parser.add_argument(
        "--speech",
        choices=("auto", "audio", "mock"),
        default="auto",
        help="audio: synthesized speech through the default engine; mock: text through the mock "
        "engine; auto: audio when espeak-ng and sox are installed",
    )
    parser.add_argument("--seed", type=int, default=1, help="the simulated teacher's")
    parser.add_argument(
        "--teacher-profile",
        choices=tuple(PROFILES),
        default="judging",  # the steering person's task 1 has a tail (41, 76 episodes of 20 runs)
        help="the simulated teacher (default: judging, which converges task 1 within 22 "
        "episodes on 20 seeds): "
        + "; ".join(f"{name} ({profile.describe()})" for name, profile in PROFILES.items()),
    )
    parser.add_argument(
        "--stall-timeout",
        type=float,
        default=120.0,
        help="seconds without a step of the robot before giving up (with --web: before "
        "warning; a session a person teaches is never given up)",
    )


def task_title(task: str, m: Map) -> str:
    """`task 2`, or `map mine.toml (Office)` for a map file."""
    return f"task {task}" if task in ("1", "2", "3", "4") else f"map {Path(task).name} ({m.name})"


def watch_of(args: argparse.Namespace) -> ConvergenceWatch:
    """The first robot's watch, judged by the map of --task and the learner's --set; a web
    demo's lasts until its person ends it."""
    m = load_map(args.task)
    convergence = convergence_on(m, with_settings(args.set))
    lasting = bool(getattr(args, "web", False))
    title = task_title(args.task, m)
    return ConvergenceWatch(
        args.robots[0], args.max_episodes, convergence, title=title, lasting=lasting
    )


def demo_table(
    robot: RobotSummary, counts: EpisodeCounts, title: str, closing: list[str] = ()
) -> str:
    """demo.md: the demo's closing lines, every episode the event log holds and the counts of
    the report's summary.md (voxshape/lab/report/counts.py), so the two files agree."""
    at = counts.convergence.converged_at
    rows = []
    for i, e in enumerate(robot.ended):
        when = "" if at is None or i < at else " (converged)" if i == at else " (after)"
        count = f"{e.interventions}{'' if e.final else '*'}"
        rows.append(
            f"| {robot.label(e)} | {e.outcome}{when} | {e.steps} | {e.seconds:.1f} | {count} |"
        )
    if any(not e.final for e in robot.ended):
        rows += ["", "\\* not the arbiter's final count: the session stopped first."]
    return "\n".join(
        [
            f"# Demo: robot {robot.robot}, {title}, taught by a simulated teacher",
            "",
            *([" ".join(closing), ""] if closing else []),
            counts.describe(),
            "",
            f"Convergence: {counts.convergence.rule()}; {INTERVENTIONS_ARE}. The same counts, "
            "from the same event log, as report/summary.md.",
            "",
            "| episode | outcome | steps | robot seconds | interventions |",
            "|---|---|---|---|---|",
            *rows,
            "",
        ]
    )


def speech_mode(choice: str) -> str:
    if choice != "auto":
        return choice
    return "audio" if shutil.which("espeak-ng") and shutil.which("sox") else "mock"


def session_name(args: argparse.Namespace) -> str:
    """Each demo is a session of its own, named by when it starts; --resume goes on with the
    latest (or --session's)."""
    session = args.session or (latest_demo() if args.resume else None)
    return session or time.strftime("demo-%Y%m%d-%H%M%S")


def demo_variables(mode: str) -> dict[str, str]:
    """The demo's defaults of the variables compose.yaml gives the services (the shell's own
    win; --session, --task, --rtf and --robots win over both)."""
    return {
        "VOXSHAPE_CLOCK": "paced",
        "VOXSHAPE_SPEECH_ENGINE": DEFAULT_ENGINE if mode == "audio" else "mock",
        # The arbiter takes the simulated teacher's delays and rate as robot seconds (it
        # reacts after as many steps as at real time, voxshape/services/simteacher), whatever --rtf.
        "VOXSHAPE_ROBOT_TIME": TEACHER,
        "VOXSHAPE_LOG_LEVEL": "WARNING",  # the services' routine logs would bury the progress
    }


def latest_demo(runs: Path = RUNS) -> str | None:
    """The session of the latest demo run in `runs` (demo-YYYYmmdd-HHMMSS; a run kept aside,
    named with a dot, is none), else None."""
    names = sorted(p.name for p in runs.glob("demo-*") if p.is_dir() and "." not in p.name)
    return names[-1] if names else None


def teacher_spec(
    session: launcher.LocalSession, args: argparse.Namespace, mode: str
) -> ServiceSpec:
    """The simulated teacher of the first robot as one more service of the session (on the
    learner's bus settings), started last."""
    bus = next(s for s in session.specs if s.name == "learner").environment
    command = ["voxshape", "sim-teacher", "--seed", str(args.seed)]
    command += ["--teacher-profile", args.teacher_profile]
    if mode == "audio":
        command.append("--audio")
    environment = {
        **bus,
        "VOXSHAPE_NODE": TEACHER,
        "VOXSHAPE_TEACHER": TEACHER,
        "VOXSHAPE_ROBOT": args.robots[0],
        "VOXSHAPE_TASK": args.task,
    }
    return ServiceSpec("sim-teacher", tuple(command), environment, ("router", "speech"), ())


def run(args: argparse.Namespace) -> int:
    launcher.interrupt_on_stop_signals()
    if args.rtf is None:
        args.rtf = float(os.environ.get("VOXSHAPE_RTF") or (1 if args.web else 10))
    if args.max_episodes < 3 or args.rtf <= 0:
        print("voxshape demo: error: --max-episodes must be >= 3 and --rtf > 0")
        return 2
    mode = speech_mode(args.speech)
    session_id = args.session = session_name(args)
    session = launcher.local_session(args, demo_variables(mode))
    simulated = not args.web or args.sim_teacher
    problem = _arrange_services(session, args, mode, simulated)
    if problem is not None:
        session.say(f"error: {problem}")
        return 2
    _introduce(session, session_id, args, mode, simulated)
    robot, progress, words = args.robots[0], watch_of(args), WordCount()
    for topic in ("episode", "teaching", "learning"):  # its steps, from the first one
        session.subscribe(topic, robot)
    session.subscribe("said", "*")
    code = _train_session(session, progress, words, args)
    now = time.monotonic()
    for line in progress.due_lines(now, flush=True, mark=code == 0):
        session.say(line)
    ending = progress.ending(code, words, now)
    if ending.learnt:
        ending = replace(ending, alone=learnt_alone(args, ending.episodes))
    closing = closing_lines(ending)
    for line in closing:
        session.say(line)
    written = outputs(session, session_id, progress, args.task, closing)
    return written or {"learnt": 0, "ended by its person": 0, "interrupted": 130}.get(ending.how, 1)


def learnt_alone(args: argparse.Namespace, episodes: int) -> Alone:
    """The demo's room and seed learnt in one process with nobody speaking, for at most
    three times the demo's episodes and 30 (a few wall seconds on a small map)."""
    began = time.monotonic()
    spec = RunSpec(args.task, "rl", args.seed, max(30, 3 * episodes), learner=tuple(args.set))
    result = run_experiment(spec)
    wall = time.monotonic() - began
    return Alone(result.converged, result.episodes, result.learning_time_s / 60, wall)


def _arrange_services(
    session: launcher.LocalSession, args: argparse.Namespace, mode: str, simulated: bool
) -> str | None:
    """Adds the simulated teacher and keeps the web page only with --web, the simulator
    last; what is wrong with compose.yaml for the demo, if anything."""
    if not {"sim", "learner", "arbiter", "speech", "logger"} <= {s.name for s in session.specs}:
        return "compose.yaml lacks a service the demo needs (sim, learner, ...)"
    if simulated:
        session.specs.append(teacher_spec(session, args, mode))
    if not args.web:  # the page only when a person teaches
        session.specs = [s for s in session.specs if s.name != "web"]
    elif launcher.web_page(session) is None:
        return "compose.yaml has no web service for --web"
    # The robot starts once its learner and teacher listen: at 20x, a start slowed by a busy
    # machine would otherwise run minutes of robot time untaught.
    session.specs.sort(key=lambda spec: spec.name == "sim")
    return None


def _introduce(
    session: launcher.LocalSession,
    session_id: str,
    args: argparse.Namespace,
    mode: str,
    simulated: bool,
) -> None:
    """Says what is about to run: the task, the robot and its speed, who teaches it, how."""
    speaks = (
        f"synthesized speech (espeak-ng) heard by the {DEFAULT_ENGINE} engine"
        if mode == "audio"
        else "text heard by the mock speech engine"
    )
    robot, others = args.robots[0], args.robots[1:]
    taught = f"a simulated {args.teacher_profile} ({PROFILES[args.teacher_profile].describe()})"
    taught = f"{taught} speaking {speaks}" if simulated else ""
    if args.web:
        taught = f"you in a browser{' and ' + taught if taught else ''}"
    session.say(
        f"voxshape demo: session {session_id!r}, {task_title(args.task, load_map(args.task))}, "
        f"robot {robot} at {args.rtf:g}x real time, taught by {taught}"
        + (f"; {', '.join(others)} also learning, untaught and not counted" if others else "")
    )


def _train_session(
    session: launcher.LocalSession,
    progress: ConvergenceWatch,
    words: WordCount,
    args: argparse.Namespace,
) -> int:
    """Starts the session, trains until done and stops it: 0, 1 on an error, 130 on Ctrl-C."""
    code = 0
    try:
        took = session.start()
        progress.started = time.monotonic()
        session.say(f"session up in {took:.1f} s: {', '.join(s.name for s in session.specs)}")
        if args.web:
            session.say(
                f"teach it in a browser: {launcher.web_page(session)} (the demo goes on, "
                "learnt or not, until you stop it: Ctrl-C)"
            )
        train(session, progress, words, args.stall_timeout, interactive=args.web)
    except (launcher.ServiceDied, launcher.LaunchAborted, BusError, TimeoutError) as e:
        session.say(f"error: {e}")
        code = 1
    except KeyboardInterrupt:
        session.say("interrupted" if not args.web else "stopping, as you asked")
        code = 130
    finally:
        session.stop()
    return code


def train(
    session: launcher.LocalSession,
    progress: ConvergenceWatch,
    words: WordCount,
    stall_timeout: float,
    interactive: bool = False,
) -> None:
    """Shows episodes as they end until convergence or the episode bound (a lasting watch:
    until Ctrl-C). A robot whose steps stop for `stall_timeout` seconds ends the demo, or
    with `interactive` (a person teaching) is reported once per stall, and it goes on."""
    bus = session.bus
    assert bus is not None
    stall, cpu_then = StallWatch(stall_timeout, time.monotonic()), session.cpu_seconds()
    warned, done_at, learnt = False, None, None
    for event in bus.events(tick=0.5):
        now = time.monotonic()
        message = event.message if isinstance(event, Input) else None
        if isinstance(message, LearningSummary):
            if stall.on_step(message.step, now) and warned:
                session.say(f"{progress.robot} goes on (step {message.step})")
                warned = False
        elif isinstance(message, EpisodeEvent):
            progress.on_episode(message, now)
        elif isinstance(message, TeachingStats):
            progress.on_teaching(message)
            words.on_teaching(message)
        elif isinstance(message, Said):
            words.on_said(message)
        elif isinstance(event, Tick):
            session.check_children()  # restarts a dead service, or raises ServiceDied
            if not stall.stalled(now):
                cpu_then = session.cpu_seconds()  # a stall's CPU figures count from here
        for line in progress.due_lines(now):
            session.say(line)
        if not learnt and (learnt := progress.learnt()) is not None:
            bus.publish(learnt)  # the pages say so (a lasting demo goes on)
            if progress.lasting:
                session.say(_learnt_now(progress))
        if progress.done:
            done_at = done_at or now
            if progress.all_shown or now - done_at > FINAL_WAIT_S:
                return
        elif stall.stalled(now) and not warned:
            what = _stalled(session, progress.robot, stall_timeout, cpu_then)
            if interactive:
                session.say(f"warning: {what}; the session goes on")
                warned = True
                continue
            session.print_stacks()
            raise TimeoutError(f"{what}: is the robot stuck? (each service's threads above)")
    raise KeyboardInterrupt


def _learnt_now(progress: ConvergenceWatch) -> str:
    """What a lasting demo says when its robot has learnt: that it goes on."""
    c = progress.convergence
    return (
        f"{progress.robot} has learnt it: {c.n_episodes} episodes ({c.learning_time / 60:.1f} "
        "robot minutes). It goes on, episode after episode: keep teaching it, or Ctrl-C to end"
    )


def _stalled(
    session: launcher.LocalSession, robot: str, timeout: float, cpu_then: dict[str, float]
) -> str:
    """What a stalled robot is said to be, with each service's CPU seconds since."""
    used = session.cpu_seconds()
    cpu = ", ".join(f"{n} {used[n] - cpu_then.get(n, 0.0):.1f}" for n in used)
    return (
        f"{robot} made no step for {timeout:g} s (CPU seconds used meanwhile: {cpu}; the sim "
        "near 0: it is blocked, not slow)"
    )


def voxshape_command() -> str:
    """How to run this installation's voxshape from here: `voxshape` when that is what the
    shell finds (an activated .venv), else its path (`make demo` runs .venv/bin/voxshape)."""
    mine = Path(sys.executable).with_name("voxshape")
    found = shutil.which("voxshape")
    if found and Path(found).resolve() == mine.resolve():
        return "voxshape"
    return os.path.relpath(mine) if mine.is_relative_to(Path.cwd()) else str(mine)


def outputs(
    session: launcher.LocalSession,
    session_id: str,
    progress: ConvergenceWatch,
    task: str,
    closing: list[str],
) -> int:
    """Writes the report and demo.md (the closing lines, then the episode table); says where
    everything is."""
    run_dir = Path("runs") / session_id
    try:
        run = RunDir.existing(run_dir)
        loaded = load_run(run)
        written = write_report(run, loaded=loaded)
    except RunError as e:
        session.say(f"error: no report: {e}")
        return 1
    robot = loaded.summary.robot(progress.robot)
    counts = loaded.counts()[progress.robot]
    table = run_dir / "demo.md"
    table.write_text(demo_table(robot, counts, task_title(task, loaded.map), closing), "utf-8")
    recording = run_dir / "recording.rrd"
    session.say(f"written under {run_dir}/ (demo.md: every episode and its words):")
    for path in [recording, table, *written]:
        session.say(f"  {path}{'' if path.exists() else '  (missing!)'}")
    session.say(f"look at it: {voxshape_command()} view {run_dir}   (or open {written[-1]})")
    return 0 if recording.exists() else 1

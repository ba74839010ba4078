"""`voxshape experiment paper|sweep|pool|distributed`: the command line of the experiments."""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
from pathlib import Path

from voxshape.lab.experiment import distributed
from voxshape.lab.experiment.cluster import ClusterError
from voxshape.lab.experiment.inprocess import PAPER_SETTINGS, SETTINGS, RunSpec
from voxshape.lab.experiment.intervals import FEW_SEEDS, few_seeds_note
from voxshape.lab.experiment.paper import PoolError, experiment, pool
from voxshape.lab.experiment.published import TASKS
from voxshape.lab.experiment.runner import ResumeError, RunsFailed
from voxshape.lab.experiment.sweep import sweep
from voxshape.runtime.settings import SettingsError, add_settings_argument, replaced
from voxshape.runtime.settings_file import write_settings
from voxshape.services.learner.config import LearnerConfig
from voxshape.services.logger.run import keep_earlier_run
from voxshape.services.simteacher.teacher import PROFILES, TeacherProfile
from voxshape.world.maps import MapError, load_map


def _names(text: str, allowed: tuple[str, ...], what: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in allowed]
    if unknown or not names:
        given = ", ".join(unknown) or "(none given)"
        raise argparse.ArgumentTypeError(
            f"unknown {what} {given}; choose from {', '.join(allowed)}"
        )
    return names


def _tasks(text: str) -> list[str]:
    """Built-in task numbers and map files, comma-separated; a map that does not load is
    refused with the loader's reason."""
    tasks = [t.strip() for t in text.split(",") if t.strip()]
    if not tasks:
        raise argparse.ArgumentTypeError(
            f"no task given; choose from {', '.join(TASKS)} or map files"
        )
    for task in tasks:
        if task not in TASKS:
            try:
                load_map(task)
            except MapError as e:
                raise argparse.ArgumentTypeError(str(e)) from None
    return tasks


def _values(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not comma-separated numbers") from None


def _add_seeds(parser: argparse.ArgumentParser, seeds: int) -> None:
    parser.add_argument(
        "--seeds",
        type=int,
        default=seeds,
        help=f"runs per task and setting (default {seeds}; below {FEW_SEEDS} the intervals "
        "say little, and the report says so)",
    )
    parser.add_argument(
        "--first-seed",
        type=int,
        default=0,
        help="seeds run: this one and the next --seeds - 1 (default 0; e.g. 30: seeds held "
        "out from choosing the defaults, which were chosen on seeds 0-29)",
    )


def _add_common(parser: argparse.ArgumentParser, seeds: int, out: str) -> None:
    _add_seeds(parser, seeds)
    parser.add_argument(
        "--max-episodes", type=int, default=150, help="then a run is censored (default 150)"
    )
    parser.add_argument(
        "--tasks",
        type=_tasks,
        default=list(TASKS),
        help="comma-separated task numbers and map files, e.g. 1,2,my-office.toml (default "
        f"{','.join(TASKS)})",
    )
    _add_out(parser, out)
    parser.add_argument("--workers", type=int, default=None, help="processes (default: cores)")
    parser.add_argument(
        "--cluster",
        default=os.environ.get("VOXSHAPE_CLUSTER") or None,
        metavar="ADDRESS",
        help="run on this Ray cluster instead of local processes: auto, ray://HOST:10001 or "
        "the head's HOST:6379 (VOXSHAPE_CLUSTER; needs voxshape[cluster])",
    )
    parser.add_argument(
        "--resume",
        type=Path,
        default=None,
        metavar="DIR",
        help="finish the interrupted experiment in DIR (in place of --out): the runs in its "
        "runs.jsonl are kept, the others run",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_settings_argument(parser, LearnerConfig, "alpha=0.1")
    parser.add_argument(
        "--teacher-profile",
        choices=tuple(PROFILES),
        default="person",
        help="the simulated teacher (default person): "
        + "; ".join(f"{name} ({profile.describe()})" for name, profile in PROFILES.items())
        + " (tireless: the teacher of earlier experiments)",
    )
    parser.add_argument(
        "--teacher",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a field of the simulated teacher's TeacherProfile "
        "(voxshape/services/simteacher/teacher.py) changed from --teacher-profile, e.g. "
        "words_per_robot_minute=2; its noise is the setting's",
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="experiment", required=True, metavar="EXPERIMENT")
    _add_paper(sub)
    _add_sweep(sub)
    _add_pool(sub)
    _add_distributed(sub)


def _add_paper(sub: argparse._SubParsersAction) -> None:
    paper = sub.add_parser(
        "paper",
        help="the paper's Tables 2 and 3 and Figure 2: 4 tasks x 4 settings x seeds",
        description="4 tasks x 4 settings x --seeds runs in parallel processes; writes "
        "results.json, report.md and figure2.png to --out",
    )
    _add_common(paper, 10, "runs/experiment-paper")
    paper.add_argument(
        "--settings",
        type=lambda s: _names(s, tuple(SETTINGS), "setting"),
        default=list(PAPER_SETTINGS),
        help=f"comma-separated from {', '.join(SETTINGS)} (default {','.join(PAPER_SETTINGS)})",
    )


def _add_sweep(sub: argparse._SubParsersAction) -> None:
    sweeping = sub.add_parser(
        "sweep",
        help="speedup of feedback against noise, reaction delay (with and without the "
        "arbiter's delay correction) and late feedback frequency",
        description="rl+f with one thing changed per point, against plain RL; writes "
        "sweep.json, sweep.md and sweep.png to --out",
    )
    _add_common(sweeping, 3, "runs/experiment-sweep")
    sweeping.add_argument("--noise", type=_values, default=[], help="e.g. 0,0.1,0.2,0.3,0.4,0.5")
    sweeping.add_argument("--delay", type=_values, default=[], help="seconds, e.g. 0,0.5,1,1.5,2")
    sweeping.add_argument(
        "--frequency",
        type=_values,
        default=[],
        help="sporadic feedback probability, e.g. 0.05,0.2,0.5",
    )
    sweeping.add_argument(
        "--rate",
        type=_values,
        default=[],
        help="the teacher's word budget, words a robot minute at salient moments, for rl+f "
        "and rl+t+f (0: the tireless teacher), e.g. 0,1,2,4,8,16",
    )


def _add_pool(sub: argparse._SubParsersAction) -> None:
    pooling = sub.add_parser(
        "pool",
        help="the runs of several `paper` outputs as one experiment (e.g. seeds 0-9 and "
        "10-19): tables and figure again",
        description="reads each DIR's results.json and writes results.json, report.md and "
        "figure2.png for all their runs to --out; the outputs must come from the same "
        "experiment (episode limit, --set, --teacher) run on other seeds",
    )
    pooling.add_argument("dirs", type=Path, nargs="+", metavar="DIR", help="`paper` outputs")
    _add_out(pooling, "runs/experiment-pool")


def _add_distributed(sub: argparse._SubParsersAction) -> None:
    distributed = sub.add_parser(
        "distributed",
        help="one task and setting in-process and with every service its own process over "
        "zenoh: same learning, how much slower",
        description="runs --task in --setting for each seed both ways and compares the "
        "episodes; writes distributed.json and distributed.md to --out",
    )
    distributed.add_argument("--task", choices=TASKS, default="1", help="default 1")
    distributed.add_argument("--setting", choices=tuple(SETTINGS), default="rl", help="default rl")
    _add_seeds(distributed, 3)
    distributed.add_argument(
        "--max-episodes", type=int, default=150, help="then censored (default 150)"
    )
    _add_out(distributed, "runs/experiment-distributed")


def _add_out(parser: argparse.ArgumentParser, out: str) -> None:
    parser.add_argument(
        "--out",
        type=Path,
        default=Path(out),
        help=f"where its results go (default {out}; results already there are kept aside)",
    )


def command_line() -> str:
    """The command being run, as results.json and the report quote it."""
    return "voxshape experiment " + shlex.join(sys.argv[2:])


def seeds_of(args: argparse.Namespace) -> range:
    return range(args.first_seed, args.first_seed + args.seeds)


def keep_earlier_results(args: argparse.Namespace) -> None:
    """An experiment writes into a fresh --out: results of an earlier one there are moved
    aside (--out.<when it ran>/), never overwritten; --resume goes on with them instead."""
    if getattr(args, "resume", None) is None and (kept := keep_earlier_run(args.out)):
        print(f"{args.out} held earlier results: kept as {kept}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    if args.experiment == "pool":
        keep_earlier_results(args)
        return run_pool(args)
    if args.seeds < 1 or args.max_episodes < 1 or args.first_seed < 0:
        print(
            "voxshape experiment: --seeds and --max-episodes must be >= 1, --first-seed >= 0",
            file=sys.stderr,
        )
        return 2
    learner, teacher = LearnerConfig(), None
    if args.experiment != "distributed":
        try:  # a bad --set or --teacher is refused before any run
            learner = replaced(LearnerConfig(), args.set)
            teacher = replaced(PROFILES[args.teacher_profile], args.teacher, "--teacher")
        except SettingsError as e:
            print(f"voxshape experiment: {e}", file=sys.stderr)
            return 2
    if few_seeds_note(args.seeds):
        print(
            f"voxshape experiment: note: {args.seeds} seed(s) per task and setting: the "
            f"intervals will say little (--seeds {FEW_SEEDS} or more for meaningful ones)",
            file=sys.stderr,
        )
    keep_earlier_results(args)
    if args.experiment == "distributed":
        return run_distributed(args, learner)
    if args.resume is not None:
        args.out = args.resume
    try:
        assert teacher is not None  # read above for paper and sweep
        running = run_sweep if args.experiment == "sweep" else run_paper
        return running(args, learner, teacher)
    except (ClusterError, ResumeError) as e:
        print(f"voxshape experiment: {e}", file=sys.stderr)
        return 2
    except RunsFailed as e:
        print(
            f"voxshape experiment: {e}\nno tables written; the finished runs are in "
            f"{args.out / 'runs.jsonl'}: add --resume {args.out} to run the rest",
            file=sys.stderr,
        )
        return 1


def record_settings(out: Path, learner: LearnerConfig, teacher: TeacherProfile | None) -> None:
    """The settings every run of an experiment learned and was taught with, in `out`'s
    settings.json beside its results: the learner's and the simulated teacher's (none in
    `distributed`, whose teacher is each setting's)."""
    write_settings(out, "learner", learner)
    if teacher is not None:
        write_settings(out, "teacher", teacher)


def run_paper(args: argparse.Namespace, learner: LearnerConfig, teacher: TeacherProfile) -> int:
    command = command_line()
    summary = experiment(
        args.out,
        args.tasks,
        args.settings,
        seeds_of(args),
        args.max_episodes,
        command,
        **_running(args),
    )
    record_settings(args.out, learner, teacher)
    _show(args.out, "report.md", f"results.json, report.md, figure2.png "
          f"({summary['wall_time_s'] / 60:.1f} min)")  # fmt: skip
    return 0


def _running(args: argparse.Namespace) -> dict:
    """How the runs of `paper` and `sweep` are run: where, by whom taught, learning how."""
    return {
        "workers": args.workers,
        "progress": not args.no_progress,
        "learner": tuple(args.set),
        "teacher": tuple(args.teacher),
        "profile": args.teacher_profile,
        "cluster": args.cluster,
        "resume": args.resume is not None,
    }


def _show(out: Path, report: str, wrote: str) -> None:
    """The report, and what was written where."""
    print((out / report).read_text())
    print(f"wrote {out}/{wrote}")


def run_pool(args: argparse.Namespace) -> int:
    command = command_line()
    try:
        summary = pool(args.dirs, args.out, command)
    except PoolError as e:
        print(f"voxshape experiment pool: {e}", file=sys.stderr)
        return 2
    # the settings the pooled results recorded (of before profiles: no teacher section)
    profile = summary.get("teacher_profile")
    record_settings(
        args.out,
        replaced(LearnerConfig(), summary.get("learner_settings", [])),
        None
        if profile is None
        else replaced(PROFILES[profile], summary.get("teacher_settings", []), "--teacher"),
    )
    _show(args.out, "report.md", f"results.json, report.md, figure2.png "
          f"({len(summary['runs'])} runs of {len(args.dirs)} experiments)")  # fmt: skip
    return 0


def run_sweep(args: argparse.Namespace, learner: LearnerConfig, teacher: TeacherProfile) -> int:
    if not (args.noise or args.delay or args.frequency or args.rate):
        print(
            "voxshape experiment sweep: give --noise, --delay, --frequency or --rate",
            file=sys.stderr,
        )
        return 2
    sweep(
        args.out,
        args.tasks,
        seeds_of(args),
        args.max_episodes,
        args.noise,
        args.delay,
        args.frequency,
        args.rate,
        **_running(args),
    )
    record_settings(args.out, learner, teacher)
    _show(args.out, "sweep.md", "sweep.json, sweep.md, sweep.png")
    return 0


def run_distributed(args: argparse.Namespace, learner: LearnerConfig) -> int:
    spec = RunSpec(args.task, args.setting, 0, args.max_episodes)
    comparison = distributed.compare(spec, list(seeds_of(args)))
    comparison["command"] = command_line()
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "distributed.json").write_text(json.dumps(comparison, indent=1))
    text = distributed.comparison_markdown(comparison) + f"\n\nReproduce: `{comparison['command']}`"
    (args.out / "distributed.md").write_text(text + "\n")
    record_settings(args.out, learner, None)
    print(text)
    print(f"wrote {args.out / 'distributed.json'}, distributed.md")
    return 0

"""The fleet's profile of the limiting process (`Profiler`: of which point, of which process).

py-spy `--gil` on the live process where py-spy is installed, else cProfile of an in-process
equivalent of one tick of the simulator, the learner, the arbiter or the page's gateway,
over ticks of the point's robots recorded here (codec included, the bus not).
"""

from __future__ import annotations

import cProfile
import io
import json
import pstats
import random
import shutil
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

from benchmarks.fleet.measure import RATE_HZ
from voxshape.protocol import Action, Observation, decode, encode, load_vocabulary

TICKS = 200  # the equivalent's ticks


# -- py-spy ---------------------------------------------------------------------------------------
def find_py_spy(given: str | None) -> str | None:
    if given:
        return given if Path(given).exists() else None
    return shutil.which("py-spy") or (
        str(Path(sys.executable).parent / "py-spy")
        if (Path(sys.executable).parent / "py-spy").exists()
        else None
    )


def py_spy_profile(py_spy: str, pid: int, seconds: float, out: Path, top: int = 12) -> str:
    """py-spy on the live process for `seconds`, only samples of the thread holding the GIL
    (`--gil`: a Python service is bound by it; zenoh's own threads waiting in native code
    would otherwise count as busy): the functions most often at the top of a stack (self)
    and anywhere in it (total)."""
    done = subprocess.run(
        [
            *(py_spy, "record", "--pid", str(pid), "--duration", f"{max(1, round(seconds))}"),
            *("--rate", "100", "--format", "raw", "--output", str(out), "--nonblocking"),
            "--gil",
        ],
        capture_output=True,
        text=True,
        timeout=seconds + 60,
    )
    if done.returncode != 0 or not out.exists():
        return f"py-spy failed ({done.returncode}): {done.stderr.strip()[-300:]}"
    own, total, samples = _gil_samples(out.read_text())
    if not samples:
        return "py-spy saw no sample holding the GIL"
    held = 100 * samples / (100 * seconds)
    lines = [
        f"py-spy --gil, 100 Hz for {seconds:g} s: {samples} samples held the GIL (about "
        f"{held:.0f}% of the time); share of them:"
    ]
    lines.append("self  total  function")
    for f, n in own.most_common(top):
        lines.append(f"{100 * n / samples:4.0f}% {100 * total[f] / samples:5.0f}%  {f}")
    lines.append("most often on the stack:")
    for f, n in total.most_common(top):
        lines.append(f"      {100 * n / samples:5.0f}%  {f}")
    return "\n".join(lines)


def _gil_samples(raw: str) -> tuple[Counter[str], Counter[str], int]:
    """Of py-spy's raw output: samples per function at the top of a stack (self), anywhere
    in it (total), and all samples."""
    own: Counter[str] = Counter()
    total: Counter[str] = Counter()
    samples = 0
    for line in raw.splitlines():
        stack, _, count = line.rpartition(" ")
        if not stack or not count.isdigit():
            continue
        n = int(count)
        samples += n
        frames = [_frame(f) for f in stack.split(";") if f and not f.startswith("process ")]
        frames = [f for f in frames if not f.startswith("thread ")]
        if frames:  # zenoh's threads run a Rust closure under Thread.run: native code
            native = frames[-1] == "Thread.run (threading.py)"
            leaf = "native code under Thread.run (zenoh's threads)" if native else frames[-1]
            own[leaf] += n
            total[leaf] += n if native else 0
        for f in set(frames):
            total[f] += n
    return own, total, samples


def _frame(text: str) -> str:
    """`fn (path/file.py:123)` -> `fn (file.py)`."""
    name, _, where = text.partition(" (")
    file = where.rstrip(")").rsplit(":", 1)[0]
    return f"{name} ({Path(file).name})" if file else name


# -- an in-process equivalent -------------------------------------------------------------------
Actor = Callable[[Observation], bytes]
Ticks = list[list[bytes]]  # each tick's encoded observations


def equivalent_profile(process: str, point: dict, task: str, top: int = 12) -> str | None:
    """cProfile of an in-process equivalent of one tick of `process` (codec included, the bus
    not), over 200 ticks of the point's robots; None when there is none for it."""
    from voxshape.services.sim.stepper import Stepper
    from voxshape.services.sim.task import Simulation
    from voxshape.world.maps import load_map

    if process not in WORKS:
        return None
    n = point["robots"]
    robots = tuple(f"r{i + 1}" for i in range(n))
    sim = Simulation(load_map(task), robots, seed=0)
    stepper = Stepper(sim, "paced", 0.5)
    act = _actor(random.Random(0))
    recorded = _record(stepper, act)
    profile = cProfile.Profile()
    work = WORKS[process](stepper, act, recorded, robots)
    t = time.process_time()
    profile.runcall(work)
    cost = (time.process_time() - t) / TICKS * 1000
    sim.close()
    text = io.StringIO()
    pstats.Stats(profile, stream=text).sort_stats("tottime").print_stats(top)
    body = "\n".join(line for line in text.getvalue().splitlines() if line.strip())
    head = (
        f"cProfile of an in-process equivalent of the {process} (its loop over {TICKS} ticks "
        f"of {n} robots, codec included, the bus and sockets not): {cost:.2f} ms CPU a tick "
        f"under the profiler (a tick's budget at {RATE_HZ:g} Hz: {1000 / RATE_HZ:.0f} ms)"
    )
    return head + "\n" + body[body.find("ncalls") :] if "ncalls" in body else head


def _actor(rng: random.Random) -> Actor:
    """A learner's answer to an observation: forward, turning at random; encoded."""

    def act(message: Observation) -> bytes:
        return encode(
            Action(
                robot=message.robot,
                episode=message.episode,
                step=message.step,
                discrete=None,
                v=0.3,
                omega=rng.uniform(-1, 1),
                chooser="policy",
            )
        )

    return act


def _record(stepper: Any, act: Actor) -> Ticks:
    """TICKS ticks of the simulator, each observation answered: the observations, encoded."""
    recorded: Ticks = []
    stepper.start()
    for _ in range(TICKS):
        sent = [m for m in stepper.step(time.monotonic()) if isinstance(m, Observation)]
        for m in sent:
            stepper.on_action(m.robot, decode(act(m), Action))
        recorded.append([encode(m) for m in sent])
    return recorded


def _sim_work(stepper: Any, act: Actor, recorded: Ticks, robots: tuple[str, ...]) -> Callable:
    """The simulator: a step, its messages encoded, the tick's actions decoded and taken."""
    actions = [[act(decode(b, Observation)) for b in tick] for tick in recorded]

    def work() -> None:
        for tick in actions:
            for message in stepper.step(time.monotonic()):
                encode(message)
            for b in tick:
                a = decode(b, Action)
                stepper.on_action(a.robot, a)

    return work


def _learner_work(stepper: Any, act: Actor, recorded: Ticks, robots: tuple[str, ...]) -> Callable:
    """The learner: each observation decoded, learned from and answered, encoded."""
    from voxshape.services.learner.checkpoint import Bookmark
    from voxshape.services.learner.config import LearnerConfig
    from voxshape.services.learner.online import OnlineLearner
    from voxshape.services.learner.sarsa import Learner

    online = {
        r: OnlineLearner(Learner(LearnerConfig(), i), Bookmark(), Counter(), 60.0)
        for i, r in enumerate(robots)
    }

    def work() -> None:
        for tick in recorded:
            for b in tick:
                obs = decode(b, Observation)
                action, summary, question = online[obs.robot].observe(obs)
                for m in (action, summary, question):
                    if m is not None:
                        encode(m)

    return work


def _arbiter_work(stepper: Any, act: Actor, recorded: Ticks, robots: tuple[str, ...]) -> Callable:
    """The arbiter: each observation decoded and followed, what it says encoded."""
    from voxshape.services.arbiter.arbiter import Arbiter
    from voxshape.services.arbiter.config import ArbiterConfig

    arbiter = Arbiter(ArbiterConfig(), load_vocabulary(), started_at=time.time())

    def work() -> None:
        for tick in recorded:
            for b in tick:
                for m in arbiter.on_observation(decode(b, Observation), time.time()):
                    encode(m)

    return work


def _web_work(stepper: Any, act: Actor, recorded: Ticks, robots: tuple[str, ...]) -> Callable:
    """The page's gateway: each observation decoded, made the pages' frames, as JSON."""
    from voxshape.services.web.gateway import Robots

    pages = Robots()

    def work() -> None:
        for k, tick in enumerate(recorded):
            for b in tick:
                for item in pages.observation(decode(b, Observation), k * 0.1):
                    json.dumps(item)

    return work


# The processes with an equivalent: the work of TICKS ticks of each
WORKS = {"sim": _sim_work, "learner": _learner_work, "arbiter": _arbiter_work, "web": _web_work}


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
        print(f"  py-spy on {process} (pid {pid}) for {self.seconds:g} s", file=sys.stderr)
        out = self.workdir / f"py-spy-{process}.txt"
        return f"{process}: " + py_spy_profile(self.py_spy, pid, self.seconds, out)

    def add_equivalent(self, done: list[dict[str, Any]], task: str) -> None:
        """The in-process profile noted, into its point."""
        if self.equivalent is None:
            return
        process, index = self.equivalent
        text = equivalent_profile(process, done[index], task) if index < len(done) else None
        done[index]["profile"] = text or f"{process}: no profile available for it"

"""The chaos and soak harness, shared by tests/test_chaos.py and benchmarks/{chaos,soak}.py.

A whole session as a person runs it: `voxshape up` (the launcher, which restarts a service that
dies, as compose's `restart` says) with the mock speech engine and the logger, plus one
simulated teacher per robot (`voxshape sim-teacher`, speaking through the speech service), all
in a working directory of its own (its runs/<session>/). Around it:

- a `Probe`: a bus node that watches what the teachers said, the notices, the feedback, the
  observations and the actions, for latencies and for what a killed logger missed;
- a `Monkey`: kills (SIGKILL) or freezes (SIGSTOP, then SIGCONT) services by pid on a schedule,
  and checks that the launcher restarted each killed one and left each frozen one alone;
- `verify()`: from the event log, the learners' checkpoints and the services' counters, did
  every word the arbiter understood reach its learner exactly once, did every learner
  converge, does the event log read to its end, does a replay show what the live recording
  shows.

Every wait is bounded; only processes started here are signalled, by pid.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import signal
import subprocess
import sys
import threading
import time
from collections import Counter, defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from protocol import (
    Action,
    CreditedFeedback,
    Observation,
    Said,
    TeacherNotice,
    Utterance,
    robot_key,
    teacher_key,
)
from services.arbiter.replies import feedback_id
from services.runtime import Input, Node, bus_config, free_loopback_port
from services.runtime.processes import end_process
from services.speech.transcriber import heard_id

ROOT = Path(__file__).resolve().parents[1]
VOXSHAPE = str(Path(sys.executable).parent / "voxshape")
SERVICES = ("router", "logger", "sim", "learner", "arbiter", "speech")  # what the monkey hits
FREEZE_S = 15.0  # longer than zenoh's lease (10 s): the frozen one's peers drop it
STOP_TIMEOUT_S = 120.0  # `voxshape up` stops services in turn, 10 s of grace each


def teacher_name(robot: str) -> str:
    return f"teacher-{robot}"


@dataclass(frozen=True)
class Fault:
    at: float  # seconds after the session started
    kind: str  # "kill" or "freeze"
    service: str


def random_schedule(seed: int, seconds: float, first: float = 20.0) -> list[Fault]:
    """A fault every 20-40 s (seeded), each a kill or a freeze of a random service."""
    rng = random.Random(seed)
    faults, at = [], first
    while at < seconds - 10:
        faults.append(Fault(at, rng.choice(("kill", "freeze")), rng.choice(SERVICES)))
        at += rng.uniform(20.0, 40.0)
    return faults


# -- the session ----------------------------------------------------------------------------
class Session:
    """`voxshape up` in `workdir` plus a simulated teacher per robot."""

    def __init__(
        self,
        workdir: Path,
        robots: tuple[str, ...],
        rtf: float,
        session_id: str = "chaos",
        seed: int = 0,
        teacher_profile: str = "person",
    ) -> None:
        self.workdir, self.robots, self.rtf, self.session_id = workdir, robots, rtf, session_id
        self.seed, self.profile = seed, teacher_profile
        self.port = free_loopback_port()
        self.router = f"tcp/127.0.0.1:{self.port}"
        self.run_dir = workdir / "runs" / session_id
        self.lines: list[str] = []  # the launcher's output, as relayed
        self.pids: dict[str, int] = {}  # service -> pid of its current process
        self.starts: dict[str, list[tuple[float, int]]] = defaultdict(list)  # (time, pid)
        self.ready = threading.Event()
        self.up: subprocess.Popen | None = None
        self.teachers: dict[str, subprocess.Popen] = {}
        self._lock = threading.Lock()
        self.started_at = 0.0

    def env(self) -> dict[str, str]:
        inherited = {k: v for k, v in os.environ.items() if not k.startswith("VOXSHAPE_")}
        return {
            **inherited,
            "PYTHONUNBUFFERED": "1",
            "VOXSHAPE_SESSION": self.session_id,
            "VOXSHAPE_SPEECH_ENGINE": "mock",
            "VOXSHAPE_CLOCK": "paced",
            "VOXSHAPE_LOG_FORMAT": "json",
            # the simulated teachers' delays are robot seconds (services/demo.py)
            "VOXSHAPE_ROBOT_TIME": ",".join(teacher_name(r) for r in self.robots),
            "VOXSHAPE_VIEWER_PORT": str(free_loopback_port()),
            "VOXSHAPE_VIEWER_BIND": "127.0.0.1",
            "VOXSHAPE_WEB_PORT": str(free_loopback_port()),
            "VOXSHAPE_WEB_ADDRESS": "127.0.0.1",
        }

    def start(self, timeout: float = 120.0) -> None:
        self.workdir.mkdir(parents=True, exist_ok=True)
        argv = [VOXSHAPE, "up", "--compose", str(ROOT / "compose.yaml"), "--port", str(self.port)]
        argv += ["--rtf", f"{self.rtf:g}", "--robots", ",".join(self.robots)]
        argv += ["--ready-timeout", "60"]
        self.up = subprocess.Popen(
            argv,
            cwd=self.workdir,
            env=self.env(),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )
        threading.Thread(target=self._read, daemon=True).start()
        if not self.ready.wait(timeout) or self.up.poll() is not None:
            raise RuntimeError("the session did not start:\n" + "\n".join(self.lines[-40:]))
        self.started_at = time.monotonic()
        for i, robot in enumerate(self.robots):
            self.teachers[robot] = self._teacher(robot, self.seed + i)

    def _teacher(self, robot: str, seed: int) -> subprocess.Popen:
        name = teacher_name(robot)
        argv = [VOXSHAPE, "sim-teacher", "--seed", str(seed), "--teacher-profile", self.profile]
        argv += ["--session", self.session_id, "--node", name, "--mode", "client"]
        argv += ["--connect", self.router, "--robot", robot, "--teacher", name]
        log = open(self.workdir / f"{name}.log", "w")  # noqa: SIM115 (closed with the process)
        return subprocess.Popen(
            argv,
            cwd=self.workdir,
            env=self.env(),
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )

    def _read(self) -> None:
        assert self.up is not None and self.up.stdout is not None
        with open(self.workdir / "up.log", "w") as copy:
            for line in self.up.stdout:
                line = line.rstrip("\n")
                copy.write(line + "\n")
                copy.flush()
                with self._lock:
                    self.lines.append(line)
                name, _, text = line.partition(" | ")
                if name.strip() == "up":
                    if text.startswith("started ") and "(pid " in text:
                        service = text.split()[1]
                        pid = int(text.split("(pid ", 1)[1].split(")", 1)[0])
                        self.pids[service] = pid
                        self.starts[service].append((time.monotonic(), pid))
                    elif text.startswith("ready in "):
                        self.ready.set()

    def alive(self, service: str) -> bool:
        pid = self.pids.get(service)
        return pid is not None and _alive(pid)

    def children(self, pid: int) -> list[int]:
        """The child processes of `pid` (the logger's renderer)."""
        try:
            tasks = Path(f"/proc/{pid}/task").iterdir()
            found = []
            for task in tasks:
                text = (task / "children").read_text().split()
                found += [int(c) for c in text]
            return found
        except OSError:
            return []

    def memory(self) -> dict[str, int]:
        """Resident memory (VmRSS, kB) of each service, the renderer and each teacher."""
        out = {}
        for service, pid in sorted(self.pids.items()):
            out[service] = rss_kb(pid)
            for child in self.children(pid):
                out[f"{service}.child"] = out.get(f"{service}.child", 0) + rss_kb(child)
        for robot, proc in self.teachers.items():
            out[teacher_name(robot)] = rss_kb(proc.pid)
        return out

    def stop(self) -> tuple[int | None, dict[str, dict], dict[str, dict]]:
        """Stops the teachers, then the session; the launcher's exit code, each service's
        last counters and each teacher's."""
        teacher_counters = {}
        for robot, proc in self.teachers.items():
            end_process(proc, 30)
            text = (self.workdir / f"{teacher_name(robot)}.log").read_text()
            teacher_counters[robot] = last_counters(text.splitlines())
        code = None if self.up is None else end_process(self.up, STOP_TIMEOUT_S)
        time.sleep(0.5)  # the reader thread takes the last lines
        with self._lock:
            lines = list(self.lines)
        by_service: dict[str, list[str]] = defaultdict(list)
        for line in lines:
            name, _, text = line.partition(" | ")
            by_service[name.strip()].append(text)
        counters = {s: last_counters(texts) for s, texts in by_service.items()}
        return code, counters, teacher_counters

    def kill_all(self) -> None:
        """Ends whatever is left (by pid): for a harness that failed halfway."""
        procs = [*self.teachers.values(), *([self.up] if self.up else [])]
        for proc in procs:
            if proc.poll() is None:
                os.kill(proc.pid, signal.SIGKILL)
                proc.wait(10)
        for pid in self.pids.values():
            if _alive(pid):
                for child in self.children(pid):
                    _signal(child, signal.SIGKILL)
                _signal(pid, signal.SIGCONT)
                _signal(pid, signal.SIGKILL)


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


def _signal(pid: int, sig: int) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, sig)


def rss_kb(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def last_counters(lines: list[str]) -> dict:
    """The last `counters` entry among JSON log lines (with their fields only)."""
    found: dict = {}
    for line in lines:
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(entry, dict) and entry.get("message") == "counters":
            found = {k: v for k, v in entry.items() if k not in ("time", "level", "logger")}
    return found


# -- the probe ------------------------------------------------------------------------------
@dataclass
class Seen:
    said: dict[str, float] = field(default_factory=dict)  # said id -> arrival
    utterances: dict[str, tuple[float, Utterance]] = field(default_factory=dict)
    notices: dict[str, TeacherNotice] = field(default_factory=dict)  # by notice id
    notice_at: dict[str, float] = field(default_factory=dict)  # utterance id -> first notice
    feedback: dict[str, CreditedFeedback] = field(default_factory=dict)
    feedback_at: dict[str, float] = field(default_factory=dict)
    obs_at: dict[tuple[str, int], float] = field(default_factory=dict)  # (robot, step)
    action_lag: list[tuple[float, float]] = field(default_factory=list)  # (time, obs->action)


class Probe:
    """A bus node of the harness's own, in a thread: what it saw and when (wall clock)."""

    def __init__(self, session: Session, keep_obs: int = 2000) -> None:
        self.session, self.keep_obs = session, keep_obs
        self.seen = Seen()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self.lock = threading.Lock()

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        s = self.session
        config = bus_config("probe", env={})
        from dataclasses import replace

        config = replace(
            config,
            session=s.session_id,
            node="probe",
            mode="client",
            connect=(s.router,),
            connect_timeout=10.0,
        )
        with Node("probe", config, quiet=True) as node:
            for robot in s.robots:
                t = teacher_name(robot)
                node.input(f"said-{robot}", teacher_key(s.session_id, t, "said"))
                node.input(f"utterance-{robot}", teacher_key(s.session_id, t, "utterance"))
                node.input(f"notice-{robot}", teacher_key(s.session_id, t, "notice"))
                node.input(f"feedback-{robot}", robot_key(s.session_id, robot, "feedback"))
                node.input(f"obs-{robot}", robot_key(s.session_id, robot, "obs"))
                node.input(f"action-{robot}", robot_key(s.session_id, robot, "action"))
            while not self._stop.is_set():
                event = node.poll(0.2)
                if isinstance(event, Input):
                    with self.lock:
                        self._on(event.message, time.time())

    def _on(self, m: object, now: float) -> None:
        seen = self.seen
        match m:
            case Said():
                seen.said.setdefault(m.id, now)
            case Utterance():
                seen.utterances.setdefault(m.id, (now, m))
            case TeacherNotice():
                seen.notices.setdefault(m.id, m)
                seen.notice_at.setdefault(m.utterance, now)
            case CreditedFeedback():
                seen.feedback.setdefault(m.id, m)
                seen.feedback_at.setdefault(m.id, now)
            case Observation():
                seen.obs_at[(m.robot, m.step)] = now
                if len(seen.obs_at) > self.keep_obs:  # oldest first: dicts keep order
                    del seen.obs_at[next(iter(seen.obs_at))]
            case Action():
                at = seen.obs_at.get((m.robot, m.step))
                if at is not None:
                    seen.action_lag.append((now, now - at))

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(15)

    def latencies(self, since: float, until: float) -> dict[str, float | None]:
        """Medians and 95th percentiles within [since, until) (wall clock): utterance ->
        its notice, utterance -> its feedback, observation -> action."""
        with self.lock:
            utterances = dict(self.seen.utterances)
            notice_at = dict(self.seen.notice_at)
            feedback = dict(self.seen.feedback)
            feedback_at = dict(self.seen.feedback_at)
            lags = [lag for t, lag in self.seen.action_lag if since <= t < until]
        to_notice, to_feedback = [], []
        for uid, (t, _) in utterances.items():
            if since <= t < until and uid in notice_at:
                to_notice.append(notice_at[uid] - t)
        for fid, fb in feedback.items():
            at = feedback_at[fid]
            times = [utterances[u][0] for u in fb.sources if u in utterances]
            if times and since <= max(times) < until:
                to_feedback.append(at - max(times))
        return {
            **_percentiles("utterance_to_notice_ms", to_notice),
            **_percentiles("utterance_to_feedback_ms", to_feedback),
            **_percentiles("obs_to_action_ms", lags),
        }


def _percentiles(name: str, values: list[float]) -> dict[str, float | None]:
    if not values:
        return {f"{name}.p50": None, f"{name}.p95": None, f"{name}.n": 0}
    a = np.array(values) * 1000
    return {
        f"{name}.p50": round(float(np.percentile(a, 50)), 1),
        f"{name}.p95": round(float(np.percentile(a, 95)), 1),
        f"{name}.n": len(values),
    }


# -- the monkey -----------------------------------------------------------------------------
@dataclass
class Injected:
    fault: Fault
    pid: int
    ok: bool  # killed: restarted with a new pid; frozen: same pid alive, not restarted
    note: str = ""


class Monkey:
    """Injects a schedule of faults into a running session, one at a time, in this thread."""

    def __init__(self, session: Session, say: Callable[[str], None] = print) -> None:
        self.session, self.say = session, say
        self.injected: list[Injected] = []
        self.before_kill = lambda service: None  # e.g. to note what a learner's kill loses

    def run(self, schedule: list[Fault], until: float) -> None:
        """Injects each fault at its time (skipping one whose service is not running, e.g.
        awaiting its restart) until `until` seconds after the session started."""
        s = self.session
        for fault in schedule:
            if not self._sleep_until(s.started_at + fault.at, s.started_at + until):
                return
            if not s.alive(fault.service):
                self.say(f"[monkey] {fault.service} is not running: {fault.kind} skipped")
                continue
            pid = s.pids[fault.service]
            if fault.kind == "kill":
                self.injected.append(self._kill(fault, pid))
            else:
                self.injected.append(self._freeze(fault, pid))
        self._sleep_until(s.started_at + until, s.started_at + until)

    def _sleep_until(self, when: float, limit: float) -> bool:
        while time.monotonic() < min(when, limit):
            if self.session.up is not None and self.session.up.poll() is not None:
                raise RuntimeError("the session stopped:\n" + "\n".join(self.session.lines[-40:]))
            time.sleep(min(0.5, max(0.0, min(when, limit) - time.monotonic())))
        return when <= limit

    def _kill(self, fault: Fault, pid: int) -> Injected:
        s = self.session
        before = len(s.starts[fault.service])
        self._said("SIGKILL", fault.service, pid)
        self.before_kill(fault.service)
        os.kill(pid, signal.SIGKILL)  # its children live on: the renderer ends by itself
        deadline = time.monotonic() + 30
        while len(s.starts[fault.service]) == before and time.monotonic() < deadline:
            time.sleep(0.1)
        restarted = len(s.starts[fault.service]) > before
        return Injected(fault, pid, restarted, "" if restarted else "not restarted within 30 s")

    def _freeze(self, fault: Fault, pid: int) -> Injected:
        s = self.session
        before = len(s.starts[fault.service])
        self._said("SIGSTOP", fault.service, pid)
        os.kill(pid, signal.SIGSTOP)
        time.sleep(FREEZE_S)
        os.kill(pid, signal.SIGCONT)
        self._said("SIGCONT", fault.service, pid)
        time.sleep(1.0)
        ok = _alive(pid) and len(s.starts[fault.service]) == before and s.pids[fault.service] == pid
        note = "" if ok else "the launcher replaced a frozen service"
        return Injected(fault, pid, ok, note)

    def _said(self, what: str, service: str, pid: int) -> None:
        self.say(
            f"[monkey] {time.monotonic() - self.session.started_at:6.1f} s: {what} {service} {pid}"
        )

    def table(self) -> dict[tuple[str, str], int]:
        return Counter((i.fault.kind, i.fault.service) for i in self.injected)


# -- the verdict ----------------------------------------------------------------------------
@dataclass
class Verdict:
    said: dict[str, int]  # robot -> words its teacher said
    understood: dict[str, int]
    reached: dict[str, int]
    lost: dict[str, list[str]]  # robot -> understood words no taken feedback holds
    duplicated: dict[str, list[str]]  # robot -> words in two or more taken feedback
    episodes: dict[str, int]
    converged: dict[str, str]  # robot -> "after N episodes" or "no"
    log_records: int
    log_tail: str | None
    replay_equal: bool
    replay_note: str
    missed: dict[str, int]  # counters `missed.*` summed over the services' last counters
    problems: list[str]

    @property
    def ok(self) -> bool:
        return not self.problems


def checkpoint_meta(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as data:
        return json.loads(str(data["meta"]))


def verify(
    session: Session,
    probe: Probe,
    counters: dict[str, dict],
    teacher_counters: dict[str, dict],
    replay: bool = True,
    convergence: bool = True,
) -> Verdict:
    """What held, from the run's files, the probe and the counters."""
    from services.logger.decoding import Known, decode_record
    from services.logger.eventlog import read_events
    from services.logger.run import RunDir
    from services.report import load_run

    problems: list[str] = []
    run = RunDir(session.run_dir)
    log = read_events(run.events)
    tail = log.describe_tail()
    # what the event log and the probe saw: utterances, notices, feedback
    notices: dict[str, TeacherNotice] = {}
    feedback: dict[str, CreditedFeedback] = {}
    utterances: dict[str, Utterance] = {}
    said_ids: dict[str, set[str]] = defaultdict(set)
    for record in log.records:
        decoded = decode_record(record)
        if not isinstance(decoded, Known):
            continue
        m = decoded.message
        if isinstance(m, TeacherNotice):
            notices.setdefault(m.id, m)
        elif isinstance(m, CreditedFeedback):
            feedback.setdefault(m.id, m)
        elif isinstance(m, Utterance):
            utterances.setdefault(m.id, m)
        elif isinstance(m, Said):
            said_ids[m.robot].add(m.id)
    with probe.lock:
        for m in probe.seen.notices.values():
            notices.setdefault(m.id, m)
        for m in probe.seen.feedback.values():
            feedback.setdefault(m.id, m)
        for _, m in probe.seen.utterances.values():
            utterances.setdefault(m.id, m)

    # A word is what a teacher said once. The mock engine's utterances derive their ids from
    # the said message (heard_id): a restarted speech service hears it again with those ids.
    # Other utterances share teacher, onset and end (an engine that hears the audio again
    # makes another utterance of it); distinct said messages may share those (two words
    # whose steps fell in one gap of the teacher's display).
    heard_in = {heard_id(s, i): (s, i) for ids in said_ids.values() for s in ids for i in (0, 1)}

    def word(utterance_id: str) -> tuple:
        if utterance_id in heard_in:
            return heard_in[utterance_id]
        u = utterances.get(utterance_id)
        return (utterance_id,) if u is None else (u.teacher, u.onset, u.end)

    understood: dict[str, set[str]] = defaultdict(set)  # robot -> understood utterance ids
    for n in notices.values():
        if n.kind == "understood":
            understood[n.robot].add(n.utterance)
    said, reached, lost, duplicated, words = {}, {}, {}, {}, {}
    for robot in session.robots:
        taken = set(checkpoint_meta(session.run_dir / f"learner-{robot}.npz")["feedback_taken"])
        by_word: dict[tuple, set[str]] = defaultdict(set)  # word -> taken feedback ids
        for fb in feedback.values():
            if fb.robot == robot and fb.id in taken:
                for u in fb.sources:
                    by_word[word(u)].add(fb.id)
        for u in understood[robot]:  # feedback of one word that nobody saw published
            for kind in ("reward", "command"):
                if (fid := feedback_id(robot, kind, (u,))) in taken:
                    by_word[word(u)].add(fid)
        heard = {word(u) for u in understood[robot]}
        words[robot] = len(heard)
        reached[robot] = sum(1 for w in heard if by_word.get(w))
        lost[robot] = sorted(str(w) for w in heard if not by_word.get(w))
        duplicated[robot] = sorted(str(w) for w, ids in by_word.items() if len(ids) > 1)
        told = teacher_counters.get(robot, {})
        said[robot] = int(told.get("sent.said", 0)) or len(said_ids[robot])
    # episodes and convergence, as the report counts them
    loaded = load_run(run)
    counts = loaded.counts()
    episodes, converged = {}, {}
    for robot in session.robots:
        c = counts.get(robot)
        episodes[robot] = 0 if c is None else c.ended
        if c is not None and c.convergence.converged:
            converged[robot] = f"after {c.convergence.n_episodes}"
        else:
            converged[robot] = "no"
    missed = Counter()
    for values in counters.values():
        for k, v in values.items():
            if k.startswith("missed."):
                missed[k] += int(v)
    replay_equal, note = (True, "not compared")
    if replay:
        replay_equal, note = compare_replay(session)
    for robot in session.robots:
        if lost[robot]:
            problems.append(f"{robot}: {len(lost[robot])} understood words never taken")
        if duplicated[robot]:
            problems.append(f"{robot}: {len(duplicated[robot])} words taken twice")
        if convergence and converged[robot] == "no":
            problems.append(f"{robot}: did not converge in {episodes[robot]} episodes")
    if not replay_equal:
        problems.append(f"replay differs from the live recording: {note}")
    return Verdict(
        said=said,
        understood=words,
        reached=reached,
        lost=lost,
        duplicated=duplicated,
        episodes=episodes,
        converged=converged,
        log_records=len(log.records),
        log_tail=tail,
        replay_equal=replay_equal,
        replay_note=note,
        missed=dict(missed),
        problems=problems,
    )


# Entities drawn for every observation at full detail, or left out when the live renderer lags
# (`thinned_scans` in recording-stats.json counts those observations); a replay never thins.
THINNED = ("/body", "/scan")


def recording_counts(path: Path) -> dict[str, int]:
    """Rows per entity of a .rrd (temporal data only)."""
    from rerun.chunk import RrdReader

    counts: Counter[str] = Counter()
    for chunk in RrdReader(path).stream().filter(is_static=False):
        counts[chunk.entity_path] += chunk.to_record_batch().num_rows
    return dict(counts)


def compare_replay(session: Session) -> tuple[bool, str]:
    """`voxshape replay` of the event log against the live recording, entity by entity: the
    same rows, but for the scans a lagging live renderer thins (fewer or as many)."""
    output = session.run_dir / "replay.rrd"
    done = subprocess.run(
        [VOXSHAPE, "replay", str(session.run_dir), "--output", str(output)],
        cwd=session.workdir,
        capture_output=True,
        text=True,
        timeout=900,
    )
    if done.returncode != 0:
        return False, f"voxshape replay failed: {done.stderr[-500:]}"
    live, again = recording_counts(session.run_dir / "recording.rrd"), recording_counts(output)
    stats = json.loads((session.run_dir / "recording-stats.json").read_text())
    thinned = int(stats.get("thinned_scans", 0))
    differ, left_out = [], Counter()
    for entity in sorted(set(live) | set(again)):
        a, b = live.get(entity, 0), again.get(entity, 0)
        kind = next((t for t in THINNED if entity.endswith(t)), None)
        if kind is not None and a <= b:
            left_out[kind] += b - a
        elif a != b:
            differ.append(f"{entity}: live {a}, replay {b}")
    for kind, n in left_out.items():  # each thinned observation lacks one row of each
        if n not in (0, thinned):
            differ.append(f"*{kind}: {n} rows fewer live, {thinned} observations thinned")
    summary = (
        f"{len(live)} entities, rows live {sum(live.values())} / replay {sum(again.values())}, "
        f"the difference the {thinned} observations the live renderer thinned"
    )
    return (not differ, summary if not differ else f"{summary}; " + "; ".join(differ[:8]))


def fault_table(monkey: Monkey) -> str:
    lines = ["| fault | service | injected | as expected |", "|---|---|---|---|"]
    grouped: dict[tuple[str, str], list[Injected]] = defaultdict(list)
    for i in monkey.injected:
        grouped[(i.fault.kind, i.fault.service)].append(i)
    for (kind, service), items in sorted(grouped.items()):
        ok = sum(i.ok for i in items)
        lines.append(f"| {kind} | {service} | {len(items)} | {ok} |")
    return "\n".join(lines)


def verdict_table(v: Verdict, robots: tuple[str, ...]) -> str:
    head = "| robot | said | understood | reached the learner | lost | duplicated | episodes |"
    lines = [head + " converged |", "|---|---|---|---|---|---|---|---|"]
    for r in robots:
        lines.append(
            f"| {r} | {v.said[r]} | {v.understood[r]} | {v.reached[r]} | {len(v.lost[r])} | "
            f"{len(v.duplicated[r])} | {v.episodes[r]} | {v.converged[r]} |"
        )
    return "\n".join(lines)


# -- learning lost to a learner kill ----------------------------------------------------------
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
    probe = Probe(session)
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
        verdict = verify(session, probe, counters, teachers, convergence=convergence)
    finally:
        session.kill_all()
    if code != 0:
        verdict.problems.append(f"voxshape up exited with {code}")
    for i in monkey.injected:
        if not i.ok:
            verdict.problems.append(f"{i.fault.kind} {i.fault.service}: {i.note}")
    return monkey, verdict, losses, {"exit": code, "counters": counters, "teachers": teachers}

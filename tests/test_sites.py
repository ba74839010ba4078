"""Two labs, one session: two sites, each a network namespace with its own router, joined by a
veth pair (the link between the labs). Router B connects to router A (`voxshape router
--connect`), and the routers route between their clients:

    site A 10.231.7.1: router A, simulator (r1), learner, arbiter, a listener
       |  veth (netem 50 ms and 1% loss each way where the kernel has it)
    site B 10.231.7.2: router B --connect tcp/10.231.7.1:7447, a teacher typing words

The teacher at site B syncs its clock with the arbiter at site A through the mesh, types
qualifiers, and each is credited by the arbiter to the steps robot r1 displayed within the
teacher's reaction window of its onset, observed from site A; nothing is lost on the way, and
only router B's connection crosses the link. Needs root (CI runs as root), as
tests/test_multihost.py does; every process is ended by its pid and the namespaces deleted.
Secured sites (one `voxshape certs` kit, router B logging in over TLS): test_sites_secured.py.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
import uuid
import warnings
from collections.abc import Callable, Iterator
from itertools import pairwise
from pathlib import Path

import pytest

from tests.conftest import ROOT, VOXSHAPE
from tests.test_multihost import ip, namespaces_unavailable
from voxshape.launcher import router_command
from voxshape.protocol import load_vocabulary
from voxshape.runtime.processes import end_process

SITE_A, SITE_B = "10.231.7.1", "10.231.7.2"
PORT = 7447
LOCAL = f"tcp/127.0.0.1:{PORT}"  # each site's router, seen from its own clients
COMPOSE = ROOT / "compose.yaml"
NETEM = ("netem", "delay", "50ms", "loss", "1%")
WORDS = ("good", "bad", "excellent", "terrible")
BETWEEN_WORDS_S = 0.8
TOLERANCE_S = 0.03  # clock sync error (rtt / 2) and the simulator's lag, on this machine


class Log:
    """A child's output file, read as it grows: its complete lines, and its JSON ones."""

    def __init__(self, path: Path) -> None:
        self.path, self._offset, self._partial = path, 0, b""
        self.lines: list[str] = []
        self.records: list[dict] = []

    def read(self) -> list[dict]:
        """New JSON records since the last read."""
        with self.path.open("rb") as f:
            f.seek(self._offset)
            data = f.read()
        self._offset += len(data)
        *complete, self._partial = (self._partial + data).split(b"\n")
        new = []
        for raw in complete:
            line = raw.decode(errors="replace")
            self.lines.append(line)
            if line.startswith("{"):
                new.append(json.loads(line))
        self.records += new
        return new

    def tail(self, n: int = 25, width: int = 240) -> str:
        self.read()
        return "\n".join(line[:width] for line in self.lines[-n:])


class Sites:
    """Two namespaces joined by a veth pair; processes started in them, ended by pid."""

    def __init__(self, folder: Path, tag: str) -> None:
        self.folder = folder
        self.ns = {"a": f"vxsa{tag}", "b": f"vxsb{tag}"}
        self.dev = {"a": f"vsa{tag}", "b": f"vsb{tag}"}  # at most 15 characters
        self.netem: str | None = None  # why netem is not on the link, or None
        self.procs: list[tuple[str, subprocess.Popen]] = []
        self.logs: dict[str, Log] = {}
        self.env = {k: v for k, v in os.environ.items() if not k.startswith("VOXSHAPE_")}
        self.env["PYTHONUNBUFFERED"] = "1"

    def make(self) -> None:
        for site in ("a", "b"):
            ip("netns", "add", self.ns[site])
            ip("-n", self.ns[site], "link", "set", "lo", "up")
        ip(
            *("link", "add", self.dev["a"], "netns", self.ns["a"], "type", "veth"),
            *("peer", "name", self.dev["b"], "netns", self.ns["b"]),
        )
        for site, address in (("a", SITE_A), ("b", SITE_B)):
            ip("-n", self.ns[site], "addr", "add", f"{address}/24", "dev", self.dev[site])
            ip("-n", self.ns[site], "link", "set", self.dev[site], "up")
        self.netem = self._add_netem()

    def _add_netem(self) -> str | None:
        if shutil.which("tc") is None:
            return "the tc command is missing (Debian package iproute2)"
        for site in ("a", "b"):
            result = subprocess.run(
                self.argv(site, "tc", "qdisc", "add", "dev", self.dev[site], "root", *NETEM),
                capture_output=True,
                text=True,
                timeout=30,
            )
            if result.returncode != 0:
                return f"tc qdisc ... {' '.join(NETEM)}: {result.stderr.strip()}"
        return None

    def argv(self, site: str, *argv: str) -> list[str]:
        return ["ip", "netns", "exec", self.ns[site], *argv]

    def start(self, site: str, name: str, argv: list[str], **kwargs: object) -> subprocess.Popen:
        """A process in `site`'s namespace (`ip netns exec` execs it: same pid), its output
        in NAME.log, its errors in NAME.err."""
        out, err = self.folder / f"{name}.log", self.folder / f"{name}.err"
        cwd = self.folder / site
        cwd.mkdir(exist_ok=True)  # the learner keeps its checkpoint under ./runs
        with out.open("wb") as stdout, err.open("wb") as stderr:
            proc = subprocess.Popen(
                self.argv(site, *argv),
                stdout=stdout,
                stderr=stderr,
                stdin=kwargs.pop("stdin", subprocess.DEVNULL),
                env=self.env,
                cwd=cwd,
                **kwargs,
            )
        self.procs.append((name, proc))
        self.logs[name] = Log(out)
        self.logs[f"{name} (stderr)"] = Log(err)
        return proc

    def end(self) -> None:
        for _, proc in reversed(self.procs):
            if proc.stdin:
                proc.stdin.close()
            end_process(proc, 10, 5)

    def delete(self) -> None:
        for name in self.ns.values():  # deleting a namespace deletes its end of the veth
            subprocess.run(["ip", "netns", "del", name], capture_output=True, timeout=30)
        for dev in self.dev.values():  # left in the root namespace if making it failed
            subprocess.run(["ip", "link", "del", dev], capture_output=True, timeout=30)

    def says(self, name: str, text: str) -> bool:
        """Whether process `name` has written `text` (out or err) so far."""
        for log in (self.logs[name], self.logs[f"{name} (stderr)"]):
            log.read()
            if any(text in line for line in log.lines):
                return True
        return False

    def report(self) -> str:
        parts = [f"netem: {self.netem or 'on'}"]
        for name, log in self.logs.items():
            if log.path.exists() and log.path.stat().st_size:
                parts.append(f"--- {name}:\n{log.tail()}")
        return "\n".join(parts)

    def until(self, done: Callable[[], object], timeout: float, what: str) -> object:
        """Polls `done` until it gives something true; fails with every log after `timeout`."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            result = done()
            if result:
                return result
            for name, proc in self.procs:
                if proc.poll() is not None and name != "teacher":
                    pytest.fail(f"{name} exited ({proc.returncode}) {what}\n{self.report()}")
            time.sleep(0.1)
        pytest.fail(f"not within {timeout} s: {what}\n{self.report()}")


@pytest.fixture
def sites(tmp_path) -> Iterator[Sites]:
    why = namespaces_unavailable()
    if why:
        pytest.skip(why)
    made = Sites(tmp_path, uuid.uuid4().hex[:6])
    try:
        try:
            made.make()
        except subprocess.CalledProcessError as e:
            pytest.skip(f"cannot make two namespaces joined by a veth pair here: {e.stderr}")
        if made.netem:
            note = f"no netem on the link ({made.netem}): the sites are joined without delay"
            print(note)
            warnings.warn(note, stacklevel=1)
        yield made
    finally:
        made.end()
        made.delete()


def bus(session: str, node: str) -> list[str]:
    return ["--session", session, "--node", node, "--mode", "client", "--connect", LOCAL]


def test_a_word_said_at_one_site_is_credited_at_the_other(sites, session_id):
    started = time.monotonic()
    router_b = start_meshed_routers(sites, session_id)
    teacher = start_both_sites(sites, session_id)
    shown = sites.logs["teacher"]

    def ready() -> bool:
        shown.read()
        events = {e["event"] for e in shown.records}
        return {"clock", "status"} <= events

    # Synced with the arbiter and seeing the robot: both through the mesh.
    sites.until(ready, 60, "the teacher at site B syncs its clock and sees robot r1")
    clock = next(e for e in shown.records if e["event"] == "clock")
    time.sleep(1.0)  # the robot has been displayed for longer than the reaction window
    for word in WORDS:
        teacher.stdin.write(f"{word}\n".encode())
        teacher.stdin.flush()
        time.sleep(BETWEEN_WORDS_S)
    teacher.stdin.close()

    seen_a = sites.logs["listen-a"]

    def all_credited() -> bool:
        seen_a.read()
        said = [u for u in of_type(seen_a, "utterance") if u["teacher"] == "ana"]
        credited = {s for f in of_type(seen_a, "feedback") for s in f["sources"]}
        return len(said) == len(WORDS) and {u["id"] for u in said} <= credited

    sites.until(all_credited, 30, f"site A credits the {len(WORDS)} words said at site B")
    sites.until(lambda: teacher.poll() is not None, 30, "the teacher has its answers")
    shown.read()
    assert teacher.returncode == 0, sites.report()
    utterances = [u for u in of_type(seen_a, "utterance") if u["teacher"] == "ana"]
    assert [u["text"] for u in utterances] == list(WORDS), sites.report()
    feedback = {f["sources"][0]: f for f in of_type(seen_a, "feedback") if "ana" in f["teachers"]}
    window = _window(of_type(seen_a, "teaching"))
    obs = of_type(seen_a, "observation")
    obs = sorted({o["step"]: o for o in obs}.values(), key=lambda o: o["step"])
    check_credited_in_window(utterances, feedback, obs, window, clock)
    watched = check_nothing_lost(sites, utterances, obs)

    links = check_across_the_link(sites, seen_a, router_b)

    link = "no netem" if sites.netem else f"link {' '.join(NETEM)} each way"
    first = sorted(c["step"] for c in feedback[utterances[0]["id"]]["credits"])
    latency = sorted(feedback[u["id"]]["sent_at"] - u["sent_at"] for u in utterances)
    rtt = clock["rtt"]
    print(
        f"two sites meshed by their routers, {link}: clock sync round "
        f"trip through the mesh {rtt * 1000:.2f} ms (offset {clock['offset'] * 1000:+.2f} ms); "
        f"word typed at B to credit published at A {latency[0] * 1000:.1f}-"
        f"{latency[-1] * 1000:.1f} ms; {len(WORDS)} of {len(WORDS)} words credited, "
        f"window {window[0]:.2f}-{window[1]:.2f} s (the first, {WORDS[0]!r}: steps "
        f"{first[0]}-{first[-1]}); {len(watched)} of {len(watched)} steps "
        f"reached B; {len(links)} connection(s) across the link, router B's; "
        f"{time.monotonic() - started:.1f} s"
    )


def check_across_the_link(sites: Sites, seen_a: Log, router_b: subprocess.Popen) -> list[int]:
    """The teacher's clock offset reached the arbiter, and only router B crosses the link:
    the processes with a connection across it."""
    teaching = of_type(seen_a, "teaching")
    stats = [t for s in teaching for t in s["teachers"] if t["teacher"] == "ana"]
    assert stats and stats[-1]["clock_offset"] is not None, stats
    links = _connections_to(sites, "b", SITE_A)
    assert links and set(links) == {router_b.pid}, (links, router_b.pid)
    return links


def of_type(log: Log, kind: str) -> list[dict]:
    """The messages of type `kind` a `voxshape listen --json` printed."""
    return [r["message"] for r in log.records if r["message"]["type"] == kind]


def start_meshed_routers(sites: Sites, session_id: str) -> subprocess.Popen:
    """Router B first: it serves its site at once, and meshes once router A answers."""
    router_b = sites.start(
        "b",
        "router-b",
        router_command(
            *("--session", session_id, "--node", "router-b"),
            *("--listen", LOCAL, "--connect", f"tcp/{SITE_A}:{PORT}"),
        ),
    )
    sites.until(lambda: sites.says("router-b", "joined the bus"), 30, "router B up alone")
    sites.start(
        "a",
        "router-a",
        router_command(
            *("--session", session_id, "--node", "router-a"),
            *("--listen", f"tcp/{SITE_A}:{PORT},{LOCAL}"),
        ),
    )
    sites.until(lambda: sites.says("router-a", "joined the bus"), 30, "router A up")
    sites.until(
        lambda: sites.says("router-b", "node joined role=router node=router-a"),
        30,
        "router B meshes with router A",
    )
    return router_b


def start_both_sites(sites: Sites, session_id: str) -> subprocess.Popen:
    """Site A: the robot's services, as compose.yaml runs them, clients of router A. Site B:
    what robot r1 shows there (to check that nothing is lost), and a teacher (returned)."""
    for name, argv in (
        ("sim", ["sim", "--clock", "paced", "--robot", "r1"]),
        ("learner", ["learner"]),
        ("arbiter", ["arbiter"]),
    ):
        sites.start("a", name, [VOXSHAPE, *argv, *bus(session_id, name)])
    sites.start("a", "listen-a", [VOXSHAPE, "listen", "--json", *bus(session_id, "listen-a")])
    obs_key = f"voxshape/{session_id}/robot/r1/obs"
    sites.start(
        "b",
        "listen-b",
        [VOXSHAPE, "listen", "--json", "--key", obs_key, *bus(session_id, "listen-b")],
    )
    return sites.start(
        "b",
        "teacher",
        [
            *(VOXSHAPE, "teach", *bus(session_id, "teacher"), "--teacher", "ana"),
            *("--robot", "r1", "--json", "--linger", "3", "--status-every", "0.5"),
        ],
        stdin=subprocess.PIPE,
    )


def check_credited_in_window(
    utterances: list[dict],
    feedback: dict[str, dict],
    obs: list[dict],
    window: tuple[float, float],
    clock: dict,
) -> None:
    """Each word, once, credited to the steps shown within the window before its onset."""
    vocabulary = load_vocabulary()
    tolerance = max(TOLERANCE_S, clock["rtt"] / 2 + 0.01)
    for u in utterances:
        f = feedback[u["id"]]
        assert f["kind"] == "reward" and f["reward"] == vocabulary.lookup(u["text"]).reward
        onset = u["onset"] + clock["offset"]  # on the arbiter's clock
        credited = {c["step"]: c["weight"] for c in f["credits"]}
        assert sum(credited.values()) == pytest.approx(1.0)
        allowed = _shown_within(obs, onset - window[1] - tolerance, onset - window[0] + tolerance)
        required = _shown_within(
            obs, onset - window[1] + tolerance, onset - window[0] - tolerance, wholly=True
        )
        assert len(required) >= 2 and required <= set(credited) <= allowed, (
            u,
            credited,
            required,
            allowed,
        )


def check_nothing_lost(sites: Sites, utterances: list[dict], obs: list[dict]) -> set[int]:
    """Every word was answered at site B, and the robot's steps that site A published while
    site B watched all reached site B: those steps."""
    shown = sites.logs["teacher"]
    notices = [e for e in shown.records if e["event"] == "notice"]
    assert sorted(n["utterance"] for n in notices) == sorted(u["id"] for u in utterances)
    assert all(n["kind"] == "understood" for n in notices), notices
    told = [e for e in shown.records if e["event"] == "feedback" and "ana" in e["teachers"]]
    assert len(told) == len(WORDS), shown.tail()
    seen_b = sites.logs["listen-b"]
    seen_b.read()
    steps_b = {r["message"]["step"] for r in seen_b.records}
    steps_a = {o["step"] for o in obs}
    assert steps_b, sites.report()
    watched = {s for s in steps_a if min(steps_b) <= s <= max(steps_b)}
    assert watched <= steps_b, f"lost at site B: {sorted(watched - steps_b)[:20]}"
    return watched


def _window(stats: list[dict]) -> tuple[float, float]:
    """The reaction window (seconds before the onset) the arbiter used for ana."""
    mine = [t for s in stats for t in s["teachers"] if t["teacher"] == "ana"]
    if not mine:
        return 0.2, 0.8
    last = mine[-1]
    return last["delay"] - last["delay_width"] / 2, last["delay"] + last["delay_width"] / 2


def _shown_within(obs: list[dict], start: float, end: float, wholly: bool = False) -> set[int]:
    """Steps displayed within [start, end] (each from its observation's wall_time until the
    next's): overlapping it, or `wholly` inside it (and the episode running)."""
    steps = set()
    for this, after in pairwise(obs):
        shown, until = this["wall_time"], after["wall_time"]
        if wholly:
            if start <= shown and until <= end and this["outcome"] == "running":
                steps.add(this["step"])
        elif shown < end and until > start:
            steps.add(this["step"])
    return steps


def _connections_to(sites: Sites, site: str, address: str) -> list[int]:
    """Pids of the processes with a TCP connection from `site` to `address`."""
    result = subprocess.run(
        sites.argv(site, "ss", "-tnpH", "state", "established", "dst", address),
        capture_output=True,
        text=True,
        timeout=30,
    )
    pids = []
    for line in result.stdout.splitlines():
        for part in line.split("pid=")[1:]:
            pids.append(int(part.split(",")[0]))
    return pids

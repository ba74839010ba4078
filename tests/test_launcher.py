"""`voxshape up`, `voxshape demo`, the CLI, and compose.yaml as the one truth of the topology."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import threading
import time
from dataclasses import replace
from pathlib import Path

import pytest

from tests.conftest import ROOT, VOXSHAPE, free_port, read_until, wait_for_port
from voxshape.cli import parser
from voxshape.launcher import (
    LocalSession,
    prepare_run,
    router_command,
    session_variables,
    without_simulator,
)
from voxshape.launcher.session import BUS_CLOSE_S
from voxshape.launcher.topology import TopologyError, interpolate, load_topology, local_variables
from voxshape.protocol import CreditedFeedback, LearningSummary
from voxshape.runtime import BusConfig, Input, Node, bus_config
from voxshape.services.logger.run import RunError

COMPOSE = ROOT / "compose.yaml"


def start_up(spawn, session_id: str, cwd: Path, *extra: str) -> tuple[subprocess.Popen, int]:
    """`voxshape up` in `cwd` (its services write under ./runs), on a free port."""
    port = free_port()
    # the web page on a port of its own: another session's may have 8080
    env = {**os.environ, "VOXSHAPE_SESSION": session_id, "VOXSHAPE_WEB_PORT": str(free_port())}
    proc = spawn(
        [VOXSHAPE, "up", "--port", str(port), *extra],
        env=env,
        text=True,
        stderr=subprocess.STDOUT,
        cwd=cwd,
    )
    return proc, port


def test_up_starts_the_compose_services_and_stops_cleanly(spawn, session_id, tmp_path):
    up, port = start_up(spawn, session_id, tmp_path, "--set", "alpha=0.1")
    lines = read_until(up, r"ready in")
    lines += read_until(up, r"teach in a browser: http://127\.0\.0\.1:\d+/")
    children = [int(m.group(1)) for line in lines if (m := re.search(r"\(pid (\d+)\)", line))]
    assert children, lines
    status = subprocess.run(
        [
            VOXSHAPE,
            "status",
            "--session",
            session_id,
            "--connect",
            f"tcp/127.0.0.1:{port}",
            "--require",
            "router",
        ],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert status.returncode == 0, status.stdout + status.stderr
    assert re.search(r"router\s+router", status.stdout)
    t0 = time.monotonic()
    up.send_signal(signal.SIGINT)
    rest, _ = up.communicate(timeout=30)
    assert up.returncode == 0, rest
    assert rest.rstrip().endswith("up     | stopped") or rest.rstrip().endswith("stopped"), rest
    print(f"voxshape up stopped {len(children)} service(s) in {time.monotonic() - t0:.2f} s")
    for pid in children:
        assert (
            not Path(f"/proc/{pid}").exists() or "zombie" in Path(f"/proc/{pid}/status").read_text()
        )
    recorded = json.loads((tmp_path / "runs" / session_id / "settings.json").read_text())
    assert recorded["learner"]["LearnerConfig"]["alpha"] == 0.1  # --set reached the learner
    started = re.search(r"service\(s\) from compose: (.*)", "\n".join(lines))
    assert started, lines
    assert sorted(recorded) == sorted(started.group(1).split(", "))  # one section per service


def compose_with(tmp_path: Path, services: str) -> Path:
    """The project's compose.yaml with more services appended."""
    compose = tmp_path / "compose.yaml"
    compose.write_text(COMPOSE.read_text() + services)
    return compose


def test_up_exits_non_zero_naming_the_service_that_died(spawn, session_id, tmp_path):
    compose = compose_with(
        tmp_path,
        """
  broken:
    command: ["voxshape", "listen", "--duration", "1"]
    environment:
      VOXSHAPE_SESSION: ${VOXSHAPE_SESSION:-default}
      VOXSHAPE_NODE: broken
      VOXSHAPE_CONNECT: ${VOXSHAPE_ROUTER:-tcp/router:7447}
    depends_on:
      router:
        condition: service_healthy
""",
    )
    up, _ = start_up(spawn, session_id, tmp_path, "--compose", str(compose))
    out, _ = up.communicate(timeout=60)
    assert up.returncode == 1, out
    assert "error: service 'broken' exited with 0; stopping the session" in out


def test_up_gives_up_on_a_service_that_never_announces_itself(spawn, session_id, tmp_path):
    compose = compose_with(
        tmp_path,
        """
  mute:
    command: ["sleep", "60"]
    depends_on: [router]
""",
    )
    up, _ = start_up(spawn, session_id, tmp_path, "--compose", str(compose), "--ready-timeout", "5")
    out, _ = up.communicate(timeout=60)
    assert up.returncode == 1, out
    # On a loaded machine slower services may be missing too: mute must be among them.
    missing = re.search(r"waited 5 s for all services; not present: (.*)", out)
    assert missing and "mute" in missing.group(1).split(", "), out


def test_up_rejects_a_broken_compose_file(tmp_path):
    compose = tmp_path / "compose.yaml"
    compose.write_text("services:\n  a:\n    command: voxshape router\n")
    result = subprocess.run(
        [VOXSHAPE, "up", "--compose", str(compose)], capture_output=True, text=True, timeout=30
    )
    assert result.returncode == 2
    assert "service 'a': `command` must be a list of strings" in result.stderr


def test_no_sim_leaves_out_the_simulator_and_what_waited_for_it(monkeypatch):
    """`voxshape up --no-sim`: a session of real robots (voxshape ros2 brings each)."""
    monkeypatch.delenv("VOXSHAPE_ROBOTS", raising=False)
    args = parser(only="up").parse_args(["up", "--no-sim", "--profile", "simteacher"])
    specs = load_topology(ROOT / "compose.yaml", session_variables(args), ("simteacher",))
    kept = without_simulator(specs)
    assert "sim" in {s.name for s in specs} and "sim" not in {s.name for s in kept}
    teacher = next(s for s in kept if s.name == "simteacher")
    assert "sim" not in teacher.depends_on and "speech" in teacher.depends_on
    assert {s.name for s in kept} == {s.name for s in specs} - {"sim"}


def test_cli_lists_its_subcommands():
    out = subprocess.run([VOXSHAPE, "--help"], capture_output=True, text=True, timeout=30).stdout
    for command in ("demo", "up", "router", "status", "listen", "vocabulary", "ros2", "placed"):
        assert re.search(rf"^\s+{command}\s", out, re.MULTILINE), command


# -- compose.yaml (the file itself: tests/test_compose.py) ------------------------------------


@pytest.mark.parametrize(
    ("text", "variables", "expected"),
    [
        ("${A:-x}", {}, "x"),
        ("${A:-x}", {"A": ""}, "x"),
        ("${A-x}", {"A": ""}, ""),
        ("${A}", {"A": "1"}, "1"),
        ("$A/$$B", {"A": "1"}, "1/$B"),
    ],
)
def test_compose_variable_interpolation(text, variables, expected):
    assert interpolate(text, variables, "t") == expected


def test_required_variable_and_dependency_errors(tmp_path):
    with pytest.raises(TopologyError, match="variable A is required: set A"):
        interpolate("${A:?set A}", {}, "t")
    with pytest.raises(TopologyError, match="nested variables are not supported"):
        interpolate("${A:-${B:-z}}", {}, "t")
    compose = tmp_path / "compose.yaml"
    compose.write_text(
        "services:\n  a: {command: [x], depends_on: [b]}\n  b: {command: [x], depends_on: [a]}\n"
    )
    with pytest.raises(TopologyError, match="dependency cycle a -> b -> a"):
        load_topology(compose, {})
    compose.write_text("services:\n  a: {command: [x], depends_on: [ghost]}\n")
    with pytest.raises(TopologyError, match="'a' depends on unknown 'ghost'"):
        load_topology(compose, {})


def test_profiles_select_optional_services(tmp_path):
    compose = tmp_path / "compose.yaml"
    compose.write_text(
        "services:\n  a: {command: [x]}\n  b: {command: [y], profiles: [extra]}\n"
        "  c: {command: [z], depends_on: [a]}\n"
    )
    assert [s.name for s in load_topology(compose, {})] == ["a", "c"]
    assert [s.name for s in load_topology(compose, {}, ("extra",))] == ["a", "b", "c"]


def router_and_sim(session_id: str, tmp_path: Path, monkeypatch) -> LocalSession:
    """compose.yaml's router and simulator as a LocalSession on a free port, not started."""
    monkeypatch.chdir(tmp_path)  # the services write under ./runs
    monkeypatch.setenv("VOXSHAPE_SESSION", session_id)  # the services' and the launcher's
    variables = local_variables()
    router = f"tcp/127.0.0.1:{free_port()}"
    variables["VOXSHAPE_ROUTER"] = variables["VOXSHAPE_ROUTER_LISTEN"] = router
    specs = [s for s in load_topology(COMPOSE, variables) if s.name in ("router", "sim")]
    return LocalSession(specs, router, ready_timeout=30)


def test_an_input_declared_before_start_hears_the_first_episode(session_id, tmp_path, monkeypatch):
    """The demo counts episodes from the first: the launcher's inputs declared before start()
    are there when it joins the bus, before the simulator starts and announces episode 0."""
    session = router_and_sim(session_id, tmp_path, monkeypatch)
    session.subscribe("episode", "r1")
    try:
        session.start()
        assert session.bus is not None
        deadline = time.monotonic() + 10
        while not isinstance(event := session.bus.poll(0.5), Input):
            assert time.monotonic() < deadline, "no episode event within 10 s"
    finally:
        session.stop()
    assert (event.message.kind, event.message.episode) == ("start", 0), event


def test_a_launcher_whose_bus_will_not_close_still_stops_its_services(
    session_id, tmp_path, monkeypatch
):
    """Ctrl-C stops the services within BUS_CLOSE_S and their own stop, even when the
    launcher's leaving the bus hangs (it once took 27 s)."""
    session = router_and_sim(session_id, tmp_path, monkeypatch)
    said: list[str] = []
    monkeypatch.setattr(session, "say", said.append)
    try:
        session.start()
        assert session.bus is not None
        close = session.bus.close
        monkeypatch.setattr(session.bus, "close", lambda: (time.sleep(BUS_CLOSE_S + 6), close()))
    finally:
        asked = time.monotonic()
        codes = session.stop()
        took = time.monotonic() - asked
    for thread in threading.enumerate():  # a zenoh close still running at exit aborts pytest
        if thread.name == "leave-bus":
            thread.join(10)
    assert took < BUS_CLOSE_S + 5.0, took
    assert codes == {"router": 0, "sim": 0}, codes
    assert any("did not close" in line for line in said), said


def test_a_service_prints_its_threads_on_sigusr1_and_goes_on(spawn, session_id):
    """What the demo does to every service when no episode ends: each says where it is."""
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    argv = router_command("--session", session_id, "--listen", endpoint)
    router = spawn(argv, text=True, stderr=subprocess.STDOUT)
    wait_for_port(port)
    router.send_signal(signal.SIGUSR1)
    lines = read_until(router, r"voxshape/deploy/router.py\", line \d+ in run$")  # its own loop
    assert any("most recent call first" in line for line in lines), lines
    time.sleep(0.5)
    assert router.poll() is None, "SIGUSR1 stopped the service"


# -- runs: each `up` a new run unless --resume; --task, --rtf, --robots --------------------------


def test_a_new_run_keeps_the_earlier_one_aside_and_resume_keeps_it(tmp_path):
    run_dir = tmp_path / "runs" / "s1"

    def prepared(resume: bool) -> str:
        line, lock = prepare_run(run_dir, resume, "up")
        lock.close()  # the session ended
        return line

    assert prepared(resume=False) == f"a new run in {run_dir}"
    (run_dir / "events.msgpack").write_bytes(b"earlier")
    line = prepared(resume=True)
    assert line.startswith(f"resuming the run in {run_dir}: no learner checkpoint"), line
    assert (run_dir / "events.msgpack").read_bytes() == b"earlier"
    line = prepared(resume=False)
    (kept,) = (p for p in run_dir.parent.iterdir() if p != run_dir)
    assert line == (
        f"{run_dir} held an earlier run: kept as {kept}; this run starts fresh (--resume "
        "continues it)"
    )
    assert re.fullmatch(r"s1\.\d{4}-\d\d-\d\dT\d\d-\d\d-\d\d", kept.name), kept.name
    assert (kept / "events.msgpack").read_bytes() == b"earlier"
    assert [p.name for p in run_dir.iterdir()] == ["session.lock"]  # held, empty
    (run_dir / "events.msgpack").write_bytes(b"later")
    prepared(resume=False)  # started in the same second: its own name
    assert len(list(run_dir.parent.iterdir())) == 3
    line = prepared(resume=True)
    assert line == f"--resume: {run_dir} holds no earlier run; this run starts fresh"


def test_a_run_folder_belongs_to_one_live_session(tmp_path):
    """A second session of the same name is refused, naming the folder, who holds it and the
    way out, and the folder is left as it is; once the first ends, it is free."""
    run_dir = tmp_path / "runs" / "default"
    _, first = prepare_run(run_dir, False, "up")
    (run_dir / "events.msgpack").write_bytes(b"live")
    with pytest.raises(RunError, match=r"runs/default belongs to a session that is running \(up"):
        prepare_run(run_dir, False, "up")
    with pytest.raises(RunError, match="--session NAME"):
        prepare_run(run_dir, True, "demo")
    assert (run_dir / "events.msgpack").read_bytes() == b"live"
    assert [p.name for p in run_dir.parent.iterdir()] == ["default"]
    first.close()
    line, second = prepare_run(run_dir, False, "up")
    second.close()
    assert "held an earlier run: kept as" in line


def test_the_flags_set_the_compose_variables(monkeypatch):
    for name in [n for n in os.environ if n.startswith("VOXSHAPE_")]:
        monkeypatch.delenv(name)
    args = parser().parse_args(["up", "--task", "2", "--rtf", "5", "--robots", "r1,r2"])
    specs = {s.name: s for s in load_topology(COMPOSE, session_variables(args), ("simteacher",))}
    for name in ("sim", "logger"):
        assert specs[name].environment["VOXSHAPE_TASK"] == "2", name
    assert specs["sim"].environment["VOXSHAPE_RTF"] == "5"
    for name in ("sim", "learner"):  # the simulator's robots, each with its learner
        assert specs[name].environment["VOXSHAPE_ROBOTS"] == "r1,r2", name
    assert specs["simteacher"].environment["VOXSHAPE_ROBOT"] == "r1"  # a robot that is there
    monkeypatch.setenv("VOXSHAPE_RTF", "3")  # a variable goes on working without its flag
    monkeypatch.setenv("VOXSHAPE_ROBOTS", "a,b")
    args = parser().parse_args(["up"])
    variables = session_variables(args)
    assert (variables["VOXSHAPE_RTF"], variables["VOXSHAPE_ROBOT"]) == ("3", "a")
    demo = parser().parse_args(["demo", "--rtf", "7"])  # the demo's own defaults otherwise
    assert (demo.task, demo.rtf, demo.robots) == ("1", 7.0, ("a", "b"))


@pytest.mark.long
def test_a_second_up_starts_a_new_run_with_fresh_learners_and_resume_resumes(
    spawn, session_id, tmp_path
):
    """Both robots of --robots move and learn, each with its learner; an earlier run is kept
    aside (its broken checkpoint is never read) and --resume goes on with the last one."""
    earlier = tmp_path / "runs" / session_id
    earlier.mkdir(parents=True)
    (earlier / "events.msgpack").write_bytes(b"earlier")
    (earlier / "learner-r1.npz").write_bytes(b"not a checkpoint")  # resuming it would fail
    robots = ("--robots", "r1,r2", "--rtf", "5")
    up, port = start_up(spawn, session_id, tmp_path, *robots)
    lines = read_until(up, r"ready in", timeout=60)
    assert any(f"runs/{session_id} held an earlier run: kept as" in line for line in lines), lines
    (kept,) = (tmp_path / "runs").glob(f"{session_id}.*")
    assert (kept / "events.msgpack").read_bytes() == b"earlier"
    learnt = learning_of(session_id, port, ("r1", "r2"))
    up.send_signal(signal.SIGINT)
    rest, _ = up.communicate(timeout=60)
    out = "\n".join([*lines, rest])
    assert up.returncode == 0, out
    for robot in ("r1", "r2"):
        assert re.search(rf"learning robot={robot} .*states=0 episodes=0", out), out
    up, port = start_up(spawn, session_id, tmp_path, *robots, "--resume")
    lines = read_until(up, r"ready in", timeout=60)
    resumed = next(line for line in lines if "resuming the run in" in line)
    assert re.search(r"learner r1 at episode \d+ \(\d+ states\), learner r2 at", resumed), lines
    up.send_signal(signal.SIGINT)
    rest, _ = up.communicate(timeout=60)
    out = "\n".join([*lines, rest])
    for robot in ("r1", "r2"):
        states = int(re.search(rf"learning robot={robot} .*states=(\d+)", out).group(1))
        assert states >= learnt[robot] > 0, (robot, out)
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == [session_id, kept.name]


def watcher(session_id: str, port: int) -> BusConfig:
    """A client of the session `voxshape up` runs on `port`."""
    return replace(
        bus_config("test", env={}),
        session=session_id,
        node="watcher",
        mode="client",
        connect=(f"tcp/127.0.0.1:{port}",),
        connect_timeout=10.0,
    )


def learning_of(session_id: str, port: int, robots: tuple[str, ...]) -> dict[str, int]:
    """States each robot's learner has, from its learning summaries once it has some."""
    states: dict[str, int] = {}
    with Node("test", watcher(session_id, port)) as node:
        for robot in robots:
            node.subscribe("learning", robot)
        deadline = time.monotonic() + 60
        while min((states.get(r, 0) for r in robots), default=0) < 3:
            assert time.monotonic() < deadline, f"learning within 60 s: {states}"
            event = node.poll(0.5)
            if isinstance(event, Input) and isinstance(event.message, LearningSummary):
                states[event.message.robot] = event.message.states
    return states


def child_pids(lines: list[str]) -> dict[str, int]:
    """The pid of each service `voxshape up` says it started (the latest start wins)."""
    started = (re.search(r"\| started (\S+) \(pid (\d+)\)", line) for line in lines)
    return {m.group(1): int(m.group(2)) for m in started if m}


def test_a_killed_service_is_restarted_and_the_session_goes_on(spawn, session_id, tmp_path):
    up, _ = start_up(spawn, session_id, tmp_path)
    learner = child_pids(read_until(up, r"ready in"))["learner"]
    os.kill(learner, signal.SIGKILL)
    lines = read_until(up, r"started learner \(pid \d+\)")
    assert any("learner was killed by SIGKILL: restarting it in 0.5 s" in x for x in lines), lines
    assert child_pids(lines)["learner"] != learner
    read_until(up, r"learner +\| .*learning")  # the new one resumes (its log says so)
    up.send_signal(signal.SIGINT)
    rest, _ = up.communicate(timeout=30)
    assert up.returncode == 0, rest


def test_with_no_restart_a_killed_service_stops_the_session(spawn, session_id, tmp_path):
    up, _ = start_up(spawn, session_id, tmp_path, "--no-restart")
    os.kill(child_pids(read_until(up, r"ready in"))["learner"], signal.SIGKILL)
    out, _ = up.communicate(timeout=60)
    assert up.returncode == 1, out
    assert "error: service 'learner' was killed by SIGKILL; stopping the session" in out


@pytest.mark.long
def test_a_service_that_keeps_dying_is_given_up_after_its_restarts(spawn, session_id, tmp_path):
    compose = compose_with(
        tmp_path,
        """
  flaky:
    command: ["voxshape", "listen", "--duration", "0.5"]
    restart: always
    environment:
      VOXSHAPE_SESSION: ${VOXSHAPE_SESSION:-default}
      VOXSHAPE_NODE: flaky
      VOXSHAPE_CONNECT: ${VOXSHAPE_ROUTER:-tcp/router:7447}
    depends_on:
      router:
        condition: service_healthy
""",
    )
    up, _ = start_up(spawn, session_id, tmp_path, "--compose", str(compose))
    out, _ = up.communicate(timeout=120)
    assert up.returncode == 1, out
    assert out.count("flaky exited with 0: restarting it in") == 5, out
    assert "service 'flaky' exited with 0 (5 restarts within 60 s: given up)" in out


def test_restart_policies_come_from_compose(tmp_path):
    specs = load_topology(COMPOSE, local_variables({}), ("simteacher", "viewer"))
    assert {s.restart for s in specs} == {"unless-stopped"}
    bad = compose_with(tmp_path, '\n  odd:\n    command: ["true"]\n    restart: sometimes\n')
    with pytest.raises(TopologyError, match="`restart` must be one of no, always"):
        load_topology(bad, local_variables({}))


@pytest.mark.timeout(240)
@pytest.mark.long
def test_up_with_the_simulated_teacher_profile_teaches_through_pocketsphinx(
    spawn, session_id, tmp_path
):
    """compose's simteacher profile speaks audio to compose's pocketsphinx: its words are
    understood and reach the learner as credited feedback."""
    up, port = start_up(spawn, session_id, tmp_path, "--profile", "simteacher", "--rtf", "2")
    read_until(up, r"ready in")
    with Node("test", watcher(session_id, port)) as node:
        node.subscribe("feedback", "r1")
        deadline, credited = time.monotonic() + 150, []
        while not credited:
            assert time.monotonic() < deadline, "no word of the simulated teacher reached r1"
            event = node.poll(0.5)
            if isinstance(event, Input) and isinstance(event.message, CreditedFeedback):
                credited.append(event.message)
    assert credited[0].teachers == ("simteacher",)
    up.send_signal(signal.SIGINT)
    rest, _ = up.communicate(timeout=60)
    assert up.returncode == 0, rest
    assert "heard teacher=simteacher" in rest  # by pocketsphinx, from its audio

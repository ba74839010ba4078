"""`voxshape logger` on a real bus: it records a real session (simulator + learner), a replay of
its event log gives the same data as its live recording, and a logger killed with SIGKILL
leaves an event log readable up to its last flush (and a recording finished without it)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import threading
import time
from pathlib import Path

from tests.conftest import VOXSHAPE, bus_args, read_until
from tests.logger_support import no_analytics, rows, scripted_session
from voxshape.protocol import EpisodeEvent, LearningSummary, Observation, decode, robot_key
from voxshape.runtime import Input, Node
from voxshape.services.logger.decoding import Known, decode_record
from voxshape.services.logger.eventlog import EventLog, read_events
from voxshape.services.logger.recording import Recorder
from voxshape.services.logger.replay import close_stream, open_stream, render
from voxshape.services.logger.run import RunDir, session_map


def start_logger(spawn, router, session_id, cwd: Path, *extra: str):
    """A logger in `cwd` (it writes ./runs/<session>), ready to render; and its renderer pid."""
    proc = spawn(
        [
            VOXSHAPE,
            "logger",
            *bus_args(router, session_id, "logger"),
            "--serve-port",
            "0",
            "--render-nice",
            "0",  # other tests may load the machine: keep the renderer's startup quick
            *extra,
        ],
        cwd=cwd,
        env={**os.environ, **no_analytics(cwd)},
        text=True,
    )
    seen: list[str] = []
    line = read_until(proc, r"renderer_pid=\d+", stream="stderr", seen=seen)[-1]
    renderer = int(re.search(r"renderer_pid=(\d+)", line).group(1))
    read_until(proc, r"voxshape.services.logger: rendering ", stream="stderr", seen=seen)
    return proc, renderer, seen


def wait_gone(pid: int, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        status = Path(f"/proc/{pid}/status")
        if not status.exists() or "zombie" in status.read_text():
            return True
        time.sleep(0.05)
    return False


def test_a_real_session_is_recorded_and_its_replay_gives_the_same_data(
    spawn, router, session_id, client_config, tmp_path
):
    logger, _, log_lines = start_logger(
        spawn,
        router,
        session_id,
        tmp_path,
        "--thin-after",
        "60",  # no thinning: compare all
    )
    seen: dict[type, list] = {Observation: [], EpisodeEvent: [], LearningSummary: []}
    with Node("test", client_config("watcher")) as node:
        for topic in ("obs", "episode", "learning"):
            node.input(topic, robot_key(session_id, "r1", topic))
        time.sleep(0.3)
        sim, learner = sim_and_learner(spawn, router, session_id, tmp_path)
        assert sim.wait(90) == 0
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline:  # what is still on its way
            event = node.poll(0.5)
            if event is None:
                break
            if isinstance(event, Input):
                seen[type(event.message)].append(event.message)
    learner.send_signal(signal.SIGTERM)
    learner.wait(30)
    logger.send_signal(signal.SIGTERM)
    _, err = logger.communicate(timeout=60)
    assert logger.returncode == 0, "\n".join(log_lines) + err
    run = RunDir(tmp_path / "runs" / session_id)
    recording = rows(run.recording)

    observations = seen[Observation]
    assert len(observations) >= 250
    assert len(recording["/world/map/poses/r1"]) == len(observations)
    assert [r[0] for r in recording["/world/map/poses/r1"]] == [o.step for o in observations]
    ends = [e for e in seen[EpisodeEvent] if e.kind != "start"]
    assert [r[-1][0] for r in recording.get("/episode/return/r1", [])] == [
        e.env_return for e in ends
    ]
    # the learner publishes its summaries with DROP congestion control: each subscriber may
    # miss some, so the recording is checked against the logger's own event log
    decoded = [decode_record(r) for r in read_events(run.events).records]
    summaries = [
        d.message
        for d in decoded
        if isinstance(d, Known) and isinstance(d.message, LearningSummary)
    ]
    assert len(seen[LearningSummary]) > 200 and len(summaries) > 200
    assert [r[0] for r in recording["/states/r1"]] == [m.step for m in summaries]
    assert recording["/states/r1"][-1][-1] == (float(summaries[-1].states),)
    session_texts = [r[-1][0] for r in recording["/log/session"]]
    assert any(t.startswith("sim sim joined") for t in session_texts)
    assert any(t.startswith("learner learner joined") for t in session_texts)

    # the live recording drew everything (no thinning), so a replay draws the same data
    stats = (run.recording_stats).read_text()
    assert '"thinned_scans": 0' in stats and '"rejected"' not in stats
    assert rows(replayed(run, tmp_path / "replay.rrd")) == recording


def sim_and_learner(
    spawn, router: str, session_id: str, tmp_path: Path
) -> tuple[subprocess.Popen, subprocess.Popen]:
    """A lockstep simulator of 250 steps and a fresh learner driving it."""
    sim_args = ("--clock", "lockstep", "--max-steps", "250", "--seed", "0", "--collision", "end")
    sim = spawn([VOXSHAPE, "sim", *bus_args(router, session_id, "sim"), *sim_args])
    checkpoint = str(tmp_path / "learner.npz")
    learner_args = ("--fresh", "--seed", "0", "--checkpoint", checkpoint)
    learner = spawn([VOXSHAPE, "learner", *bus_args(router, session_id, "learner"), *learner_args])
    return sim, learner


def replayed(run: RunDir, out: Path) -> Path:
    """The run's event log drawn again into `out`, as `voxshape replay` does."""
    world = session_map(run)
    stream, _ = open_stream("replay", out, world)
    recorder = Recorder(stream, world)
    recorder.start()
    render(read_events(run.events).records, recorder)
    close_stream(stream)
    return out


def test_a_killed_logger_leaves_its_event_log_readable_up_to_its_last_flush(
    spawn, router, session_id, client_config, tmp_path
):
    logger, renderer, _ = start_logger(spawn, router, session_id, tmp_path)
    script = scripted_session(session_id, episodes=6, steps=60)
    published: list[str] = []
    stop = threading.Event()
    with Node("test", client_config("teacher")) as node:
        outputs = {}
        for key, _ in script.messages:
            if key not in outputs:
                outputs[key] = node.output(key.rsplit("/", 1)[-1], key)
        time.sleep(0.5)  # the subscriptions reach the router

        def publish(messages) -> None:
            for key, message in messages:
                if stop.is_set():
                    return
                outputs[key].put(message)
                published.append(message.id)
                time.sleep(0.0005)

        half = len(script.messages) // 3
        publish(script.messages[:half])
        time.sleep(0.5)  # 10 flush intervals: all of these are on disk
        flushed = len(published)
        writer = threading.Thread(target=publish, args=(script.messages[half:],))
        writer.start()
        time.sleep(0.2)
        os.kill(logger.pid, signal.SIGKILL)  # mid-session, while messages arrive
        killed_at = len(published)
        stop.set()
        writer.join(10)
    logger.wait(10)
    assert killed_at > flushed  # it was killed while messages kept coming

    run = RunDir(tmp_path / "runs" / session_id)
    log = read_events(run.events)  # no error: at worst an incomplete last record
    logged = [(r.key, decode(r.payload).id) for r in log.records if "/presence/" not in r.key]
    ids = [i for _, i in logged]
    assert set(published[:flushed]) <= set(ids) and len(set(ids)) == len(ids)  # once each
    # in order per key, as zenoh orders them (a message dropped on the way and fetched back
    # from its publisher's cache comes after later ones of other keys)
    order = {i: n for n, i in enumerate(published)}
    for key in {k for k, _ in logged}:
        mine = [order[i] for k, i in logged if k == key]
        assert mine == sorted(mine), key

    # the renderer saw its logger die, drew the rest of the log, and closed the recording
    finished = wait_gone(renderer, 60)
    if not finished:
        os.kill(renderer, signal.SIGKILL)  # started (by the logger) for this test: end it
    assert finished, "the renderer did not finish after its logger died"
    observations = sum(r.key.endswith("/obs") for r in log.records)
    assert len(rows(run.recording, "/world/map/poses/**")["/world/map/poses/r1"]) == observations

    check_started_again(spawn, router, session_id, tmp_path, log)


def check_started_again(spawn, router: str, session_id: str, tmp_path: Path, log: EventLog) -> None:
    """A logger started again in this session cuts off what the killed one left half-written
    (`log`) and appends after it."""
    again, _, lines = start_logger(spawn, router, session_id, tmp_path)
    if log.incomplete_tail:
        assert any("cut off an incomplete last record" in line for line in lines), lines
    again.send_signal(signal.SIGTERM)
    again.wait(30)
    resumed = read_events(RunDir(tmp_path / "runs" / session_id).events)
    assert resumed.incomplete_tail == 0 and resumed.records[: len(log.records)] == log.records
    assert len(resumed.records) > len(log.records)  # its own presence, at least

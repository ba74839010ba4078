"""The logger's recording, replay, report and viewer on a scripted session (no bus): read the
.rrd back and check what a person would look at."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import time
import urllib.request

import msgpack
import pytest
from rerun.chunk import RrdReader

from tests.conftest import VOXSHAPE, free_port
from tests.logger_support import (
    listening_on,
    no_analytics,
    rows,
    scripted_session,
    write_script,
)
from voxshape.cli import main
from voxshape.lab.report import write_report
from voxshape.lab.report.pictures import moving_average
from voxshape.lab.report.summary import summarize_session
from voxshape.protocol import encode
from voxshape.protocol.examples import example_messages
from voxshape.services.logger.decoding import decode_record
from voxshape.services.logger.eventlog import EventLogWriter, EventRecord, pack_gap, read_events
from voxshape.services.logger.recording import Recorder
from voxshape.services.logger.replay import ScanThinning, close_stream, open_stream, render
from voxshape.services.logger.run import RunDir, describe_session, session_map, write_session_info


@pytest.fixture
def scripted_run(tmp_path):
    """A run directory holding the event log of a scripted session."""
    run = RunDir(tmp_path / "runs" / "s1")
    write_session_info(run, describe_session("s1", "1", {"task": "1"}))
    script = scripted_session("s1", episodes=3, steps=20)
    write_script(run.events, "s1", script)
    return run, script


def render_file(run: RunDir, output, detail=None):
    """Renders the run's event log into `output` in this process."""
    world = session_map(run)
    stream, _ = open_stream("s1-test", output, world)
    recorder = Recorder(stream, world)
    recorder.start()
    if detail is None:
        render(read_events(run.events).records, recorder)
    else:
        for i, record in enumerate(read_events(run.events).records):
            recorder.record(decode_record(record), detail=detail(i))
        recorder.flush()
    close_stream(stream)
    return recorder


def test_the_recording_holds_poses_feedback_steps_and_episode_returns(scripted_run, tmp_path):
    run, script = scripted_run
    output = tmp_path / "x.rrd"
    recorder = render_file(run, output)
    assert recorder.counters["thinned_scans"] == 0
    data = rows(output)
    assert len(data["/world/map/poses/r1"]) == script.observations  # one pose per step
    assert len(data["/world/map/robots/r1/scan"]) == script.observations
    # the teacher reward sits at the step it was credited to, the marker where it arrived
    ((step, *_rest, value),) = data["/reward/teacher/r1"]
    assert (step, value) == (script.feedback_credited_step, (10.0,))
    assert data["/reward/feedback/r1"][0][0] == script.feedback_arrival_step
    texts = {r[-1][0]: r[0] for r in data["/log/r1"]}  # text -> step
    assert texts["ana: reward +10, credited to step 29"] == script.feedback_arrival_step
    # the learning curve: each episode's return at its last step, and its interventions (the
    # arbiter's final count, drawn at its end once it comes: never for the last one here)
    returns = [r[-1][0] for r in sorted(data["/episode/return/r1"])]
    assert returns == [script.returns[e] for e in range(3)]
    interventions = [(*r[:2], r[-1][0]) for r in sorted(data["/episode/interventions/r1"])]
    assert interventions == [(20, 0, 0.0), (41, 1, 1.0)]
    assert "episode 1 ends: timeout after 20 steps, return -20" in texts
    assert texts["episode 1: 1 intervention(s), the arbiter's final count"] == 41
    # timelines: steps, simulated time in nanoseconds, the logger's wall clock
    step, episode, sim_ns, wall_ns, _ = data["/world/map/poses/r1"][-1]
    assert (episode, sim_ns) == (2, round(step * 0.1 * 1e9))
    assert wall_ns == pytest.approx(read_events(run.events).records[-1].received * 1e9, abs=1e8)
    # static: the map (y-up flip), and the default layout
    reader = RrdReader(output)
    assert reader.blueprints(), "no blueprint: the default view would be rerun's guess"
    statics = {c.entity_path for c in reader.stream().filter(is_static=True)}
    assert {"/world/map", "/world/map/static/walls", "/world/map/static/goal"} <= statics


def test_unknown_message_types_become_text_and_rejects_are_counted(tmp_path):
    run = RunDir(tmp_path / "runs" / "s1")
    write_session_info(run, describe_session("s1", "1", {}))
    newer = msgpack.packb({"schema": 1, "type": "arbiter_stats", "dropped": 3}, use_bin_type=True)
    with EventLogWriter(run.events, "s1") as writer:
        writer.append(EventRecord(1.7e9, "voxshape/s1/robot/r1/arbiter", "put", newer))
        writer.append(EventRecord(1.7e9 + 1, "voxshape/s1/robot/r1/obs", "put", b"junk"))
        writer.append(EventRecord(1.7e9 + 2, "voxshape/s1/presence/sim/sim", "put", b""))
    recorder = render_file(run, tmp_path / "x.rrd")
    assert recorder.counters["unknown_types"] == 1 and recorder.counters["rejected"] == 1
    texts = [r[-1][0] for r in rows(tmp_path / "x.rrd")["/log/session"]]
    assert "arbiter_stats on voxshape/s1/robot/r1/arbiter: dropped=3" in texts
    assert any(t.startswith("rejected #1 on voxshape/s1/robot/r1/obs:") for t in texts)
    assert "sim sim joined the session" in texts


def test_messages_before_a_robot_s_first_step_or_of_no_robot_are_drawn(tmp_path):
    """A word said before the robot's first step, or to a robot that is not there (`teach
    --robot r9`), and whatever follows from it, is drawn at its wall time; a gap too."""
    run = RunDir(tmp_path / "runs" / "s1")
    write_session_info(run, describe_session("s1", "1", {}))
    with EventLogWriter(run.events, "s1") as writer:
        for k, (key, message) in enumerate(example_messages("s1", robot="r9")):
            if not key.endswith(("/obs", "/episode")):  # r9 never steps
                writer.append(EventRecord(1.7e9 + k, key, "put", encode(message)))
        writer.append(EventRecord(1.8e9, "voxshape/s1/robot/r9/obs", "gap", pack_gap(7, "z/1")))
    recorder = render_file(run, tmp_path / "x.rrd")
    assert recorder.counters["not_drawn"] == 0 and recorder.counters["missed"] == 7
    texts = [r[-1][0] for r in rows(tmp_path / "x.rrd")["/log/teachers/ana"]]
    assert any("ana to r9: 'muy bien'" in t for t in texts)


def test_a_record_that_cannot_be_drawn_is_counted_and_the_rest_drawn(scripted_run, tmp_path):
    run, _ = scripted_run
    out = tmp_path / "x.rrd"
    broken = Recorder._episode

    def failing(self, decoded, event):
        if event.episode == 1:
            raise RuntimeError("a bug drawing episode 1")
        broken(self, decoded, event)

    Recorder._episode = failing
    try:
        recorder = render_file(run, out)
    finally:
        Recorder._episode = broken
    assert recorder.counters["not_drawn"] == 2  # its start and its end
    assert len(rows(out)["/episode/return/r1"]) == 2  # the other two episodes' ends


def test_thinning_leaves_out_scans_not_poses_and_counts_them(scripted_run, tmp_path):
    run, script = scripted_run
    thinning = ScanThinning(lag_limit=0.5, keep_one_in=10)
    assert [thinning.detail(0.1)] + [thinning.detail(2.0) for _ in range(20)] == (
        [True] + [i % 10 == 0 for i in range(20)]
    )
    recorder = render_file(run, tmp_path / "thin.rrd", detail=lambda i: i % 2 == 0)
    data = rows(tmp_path / "thin.rrd")
    thinned = recorder.counters["thinned_scans"]
    assert 0 < thinned < script.observations
    assert len(data["/world/map/poses/r1"]) == script.observations
    assert len(data["/world/map/robots/r1/scan"]) == script.observations - thinned


def test_replay_command_renders_what_the_recorder_draws_and_explains_bad_input(
    scripted_run, tmp_path, capsys
):
    run, _ = scripted_run
    first = subprocess.run(
        [VOXSHAPE, "replay", str(run.path)], capture_output=True, text=True, timeout=60
    )
    assert first.returncode == 0, first.stderr
    assert (run.path / "replay.rrd").is_file() and "records in" in first.stdout
    render_file(run, tmp_path / "again.rrd")
    assert rows(run.path / "replay.rrd") == rows(tmp_path / "again.rrd")

    assert main(["replay", str(tmp_path / "runs" / "nope")]) == 2
    assert "no run directory" in capsys.readouterr().err
    size = run.events.stat().st_size
    with run.events.open("ab") as f:  # a killed logger's half record: a warning, not an error
        f.write(encode(scripted_session("s1").messages[3][1])[:50])
    assert main(["replay", str(run.path), "--output", str(tmp_path / "torn.rrd")]) == 0
    assert "bytes of an incomplete record" in capsys.readouterr().err
    with run.events.open("r+b") as f:  # damage in the middle: an error naming the fix
        f.seek(size - 200)
        f.write(b"\xc1" * 10)
    assert main(["replay", str(run.path)]) == 2
    assert "truncate -s" in capsys.readouterr().err


def test_report_draws_pictures_and_sums_up(scripted_run, capsys):
    run, script = scripted_run
    summary = summarize_session(read_events(run.events).records, "s1")
    robot = summary.robots["r1"]
    assert [e.env_return for e in robot.ended] == [script.returns[e] for e in range(3)]
    assert [e.interventions for e in robot.ended] == [0, 1, 0]
    assert robot.credits == [(script.feedback_credited_step, 10.0)]
    assert robot.words == [(script.feedback_arrival_step, 10.0, "ana")]
    assert list(moving_average([1, 2, 3, 4], 2)) == [1.0, 1.5, 2.5, 3.5]
    paths = write_report(run)
    for png in paths[:-1]:
        assert png.suffix == ".png" and png.stat().st_size > 10_000, png
    text = paths[-1].read_text()
    assert "3: 2 goal, 0 collision, 1 timeout" in text and "trajectories-r1.png" in text
    assert main(["report", str(run.path), "--episodes", "7"]) == 2
    assert "robot r1 has no episode 7 (it has 0-2)" in capsys.readouterr().err


def test_view_serves_the_web_viewer_on_localhost_and_prints_its_url(
    spawn, scripted_run, tmp_path, capsys
):
    run, _ = scripted_run
    render_file(run, run.recording)
    env = {**os.environ, **no_analytics(tmp_path)}
    env.pop("DISPLAY", None)
    env.pop("WAYLAND_DISPLAY", None)
    web, grpc = free_port(), free_port()
    view = spawn(
        [VOXSHAPE, "view", str(run.path), "--web-port", str(web), "--grpc-port", str(grpc)],
        env=env,
        text=True,
    )
    line = view.stdout.readline()
    url = re.search(r"(http://127\.0\.0\.1:\d+/\?url=\S+)", line).group(1)
    assert f"127.0.0.1%3A{grpc}" in url
    deadline, status = time.monotonic() + 30, None
    while time.monotonic() < deadline and status is None:
        try:
            status = urllib.request.urlopen(url, timeout=2).status
        except OSError:
            time.sleep(0.2)
    assert status == 200
    assert listening_on(web) == {"127.0.0.1"} and listening_on(grpc) == {"127.0.0.1"}
    os.kill(view.pid, signal.SIGTERM)
    view.wait(20)
    assert not listening_on(web), "the viewer outlived `voxshape view`"
    assert main(["view", "--viewer-port", str(free_port())]) == 2
    assert "no live recording at" in capsys.readouterr().err


def test_rerun_is_not_imported_by_commands_that_do_not_draw():
    code = "import sys, voxshape.cli; print('rerun' in sys.modules)"
    out = subprocess.run(
        [os.path.join(os.path.dirname(VOXSHAPE), "python"), "-c", code],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.stdout.strip() == "False"


def test_a_following_renderer_keeps_no_index_of_every_chunk(tmp_path, monkeypatch):
    """A live recording is sent in many small chunks for hours; rerun's file footer, an index
    of every chunk held in memory until the file closes, grew the renderer by ~27 MB a minute
    with four robots (benchmarks/soak.py). A follower writes none; its file still reads; a
    one-shot replay keeps its footer."""
    import numpy as np
    import rerun as rr
    from rerun.error_utils import RerunWarning

    from voxshape.services.logger import replay

    stream, _ = open_stream("s1", tmp_path / "live.rrd", None, footer=False)
    for k in range(50):
        stream.send_columns(
            "states/r1",
            indexes=[rr.TimeColumn("step", sequence=[k])],
            columns=rr.Scalars.columns(scalars=np.array([float(k)])),
        )
    close_stream(stream)
    with pytest.warns(RerunWarning, match="no footer"):
        reader = RrdReader(tmp_path / "live.rrd")
    assert sum(c.to_record_batch().num_rows for c in reader.stream().filter(is_static=False)) == 50

    run = RunDir(tmp_path / "run")
    run.path.mkdir()
    with EventLogWriter(run.events, "s1"):
        pass
    write_session_info(run, describe_session("s1", "1", {}))
    footers = []

    class Opened(Exception):
        pass

    def opened(*args, footer: bool = True, **kw):
        footers.append(footer)
        raise Opened  # enough: how it would have opened the stream

    monkeypatch.setattr(replay, "open_stream", opened)
    for argv in (["replay", str(run.path)], ["replay", str(run.path), "--follow"]):
        with pytest.raises(Opened):
            main(argv)
    assert footers == [True, False]

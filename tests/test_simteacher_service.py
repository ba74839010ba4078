"""`voxshape sim-teacher`: its timing between the bus and the core, and on a real bus its words
reach the arbiter through the speech service (mock text, or espeak-ng audio to pocketsphinx)."""

from __future__ import annotations

import shutil
import subprocess
import time
from dataclasses import replace

import pytest

from tests.conftest import VOXSHAPE, bus_args
from voxshape.protocol import (
    HelpRequest,
    Observation,
    TeacherNotice,
    load_vocabulary,
    robot_key,
    teacher_key,
)
from voxshape.runtime import Input, Node, Presence
from voxshape.services.arbiter.scripted import observation
from voxshape.services.simteacher.display import DisplayClock, DisplayTeacher
from voxshape.services.simteacher.synthesis import synthesize
from voxshape.services.simteacher.teacher import TIRELESS, SimulatedTeacher
from voxshape.world.geodesic import path_command
from voxshape.world.maps import load_map

TASK = load_map("1")


def obs(step: int, x: float, episode: int = 0, episode_step: int | None = None) -> Observation:
    """Robot r1 of task 1 at (x, y of the start) at `step`, shown at 1000 + step."""
    shown = observation("r1", step, 1000.0 + step, episode=episode, episode_step=episode_step)
    return replace(shown, x=x, y=TASK.start.y)


def teacher(**profile: float) -> SimulatedTeacher:
    return SimulatedTeacher(TASK, load_vocabulary(), replace(TIRELESS, **profile), seed=1)


def test_the_display_clock_gives_the_time_each_step_was_shown():
    clock = DisplayClock()
    for k in range(10):
        clock.shown(k * 0.1, 50.0 + k * 0.01)  # a fast-forwarded display: 10 steps in 0.1 s
    assert clock.at(0.3) == pytest.approx(50.03)
    assert clock.at(0.25) == pytest.approx(50.03)  # the first step at or after
    assert clock.at(5.0) == pytest.approx(50.09)  # not shown yet: the latest
    clock.shown(0.0, 60.0)  # the simulator started over
    assert clock.at(0.0) == 60.0


def test_words_are_sent_once_said_with_onset_and_end_at_the_display_times():
    """Robot time drives the teacher; its words carry the own-clock display times of the steps
    at their onset and end, however fast the display runs."""
    core = teacher(delay=0.5, jitter=0.0)
    bus = DisplayTeacher(core, max_words_per_robot_s=100.0)
    sent = []
    for k in range(40):  # 0.05 m a step towards the goal, then it stands still
        x = TASK.start.x + 0.05 * min(k, 12)
        at = 2000.0 + 0.004 * k  # shown every 4 ms of the teacher's clock
        for spoken in bus.on_observation(obs(k, x), at):
            sent.append((k, spoken))
    assert sent, bus.counters
    for k, spoken in sent:
        assert spoken.kind == "judgement"
        assert spoken.end == pytest.approx(2000.0 + 0.004 * k)  # sent when its end is shown
        # speaking takes 0.4 robot s: 4 steps of 4 ms
        assert spoken.end - spoken.onset == pytest.approx(0.016, abs=1e-9)
    assert bus.counters["said.judgement"] == len(sent)


def test_it_answers_the_robots_question_with_the_way_after_its_reaction():
    core = teacher(delay=0.5, jitter=0.0, words_per_robot_minute=4.0)
    bus = DisplayTeacher(core, max_words_per_robot_s=100.0)
    bus.on_observation(obs(0, TASK.start.x, episode_step=0), 2000.0)
    question = HelpRequest(
        robot="r1", episode=0, step=0, reason="stuck", detail="stuck", x=TASK.start.x, y=0.0
    )
    bus.on_question(question)
    said = [s for k in range(1, 20) for s in bus.on_observation(obs(k, TASK.start.x), 2000.0 + k)]
    answers = [s for s in said if s.kind == "answer"]
    assert [s.text for s in answers] == [path_command(TASK, TASK.start.x, TASK.start.y, 0.0)]
    assert answers[0].onset == 2005.0  # 0.5 robot s after the question's step was shown
    silent = DisplayTeacher(teacher(answers=False), max_words_per_robot_s=100.0)
    silent.on_observation(obs(0, TASK.start.x, episode_step=0), 2000.0)
    silent.on_question(question)
    assert not [
        s
        for k in range(1, 20)
        for s in silent.on_observation(obs(k, TASK.start.x), 2000.0 + k)
        if s.kind == "answer"
    ]


def test_it_never_says_more_than_its_most_words_a_robot_second():
    """However fast the display runs: 20 robot seconds shown in 0.2 s of its clock."""
    bus = DisplayTeacher(teacher(delay=0.0, jitter=0.0, interval=0.1), max_words_per_robot_s=2.0)
    said = 0
    for k in range(200):
        x = TASK.start.x + 0.3 * (k % 12)  # 0.3 m a step, then back: a judgement every look
        said += len(bus.on_observation(obs(k, x), 10.0 + k * 0.001))
    assert 38 <= said <= 42  # 20 robot seconds at 2/s, burst 2
    assert bus.counters["unsaid.judgement.too_fast"] > 100
    restarted = [  # a new simulator: steps from 0 again, its rate anew
        bus.on_observation(obs(k, TASK.start.x + 0.3 * (k % 12), 1, k), 11.0 + k) for k in range(30)
    ]
    assert sum(map(len, restarted)) >= 4  # 3 robot seconds at 2/s (not the old clock's)


def test_it_dictates_commands_during_the_first_episodes_it_sees_start():
    bus = DisplayTeacher(teacher(), traces=1, max_words_per_robot_s=100.0)
    first = [s for k in range(20) for s in bus.on_observation(obs(k, TASK.start.x), 5.0 + k)]
    assert first and {s.kind for s in first} == {"command"}
    assert len(first) == 4  # one every 0.5 robot seconds: 2 s of robot time
    assert {s.text for s in first} <= {"forward", "left", "right"}
    later = [
        s
        for k in range(20, 60)
        for s in bus.on_observation(
            obs(k, TASK.start.x + 0.05 * (k - 20), episode=1, episode_step=k - 20), 5.0 + k
        )
    ]
    assert all(s.kind == "judgement" for s in later)


@pytest.mark.skipif(not (shutil.which("espeak-ng") and shutil.which("sox")), reason="no espeak")
def test_synthesized_speech_is_16_khz_with_quiet_around_it():
    samples = synthesize("excellent")
    assert 0.8 < len(samples) / 16000 < 2.5
    assert abs(samples[:1000]).max() < 50 and abs(samples[-1000:]).max() < 50  # dither
    assert abs(samples).max() > 10000


def _teach_through_speech(spawn, router, session_id, client_config, tmp_path, engine: list[str]):
    """A robot standing still while a fake simulator moves it forward then back: the arbiter's
    notices say what of the teacher's words it understood."""
    args = lambda node: bus_args(router, session_id, node)  # noqa: E731
    spawn([VOXSHAPE, "arbiter", *args("arbiter")], cwd=tmp_path)
    spawn([VOXSHAPE, "speech", *args("speech"), *engine], cwd=tmp_path)
    audio = ["--audio"] if "pocketsphinx" in engine else []
    skew = "0" if audio else "3"  # the mock hears text on a clock 3 s ahead
    teacher_proc = spawn(
        [
            VOXSHAPE,
            "sim-teacher",
            *args("simteacher"),
            "--teacher",
            "ana",
            "--teacher-profile",
            "tireless",  # a word at every look: enough to see in 8 s
            *audio,
            "--clock-skew",
            skew,
            "--seed",
            "1",
        ],
        cwd=tmp_path,
        stderr=subprocess.STDOUT,
        text=True,
    )
    notices: list[TeacherNotice] = []
    with Node("test", client_config("fake-sim")) as node:
        node.watch_presence()
        node.input("notice", teacher_key(session_id, "ana", "notice"))
        out = node.output("obs", robot_key(session_id, "r1", "obs"))
        present: set[str] = set()
        deadline = time.monotonic() + 30
        while not {"arbiter", "speech", "simteacher"} <= present and time.monotonic() < deadline:
            event = node.poll(0.1)
            if isinstance(event, Presence) and event.alive:
                present.add(event.node)
        time.sleep(2.0)  # subscriptions, the speech model, the teacher's clock sync
        x0, period = TASK.start.x, 0.05  # 2x real time: a step every 50 ms of wall time
        for k in range(160):  # forward 0.05 m a step for 8 s of robot time, then back
            x = x0 + 0.05 * (k if k < 80 else 160 - k)
            time.sleep(period)
            message = obs(k, x)
            out.put(replace(message, wall_time=time.time()))
            while (event := node.poll(0)) is not None:
                if isinstance(event, Input):
                    notices.append(event.message)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and len(notices) < 6:
            event = node.poll(0.1)
            if isinstance(event, Input):
                notices.append(event.message)
    assert teacher_proc.poll() is None
    return notices


def test_its_text_reaches_the_arbiter_through_the_mock_speech_engine(
    spawn, router, session_id, client_config, tmp_path
):
    notices = _teach_through_speech(
        spawn, router, session_id, client_config, tmp_path, ["--engine", "mock"]
    )
    meanings = [n.meaning for n in notices if n.kind == "understood"]
    assert len(meanings) >= 6, notices
    assert {"good", "excellent"} & set(meanings[:3]) and {"bad", "terrible"} & set(meanings)


@pytest.mark.skipif(not (shutil.which("espeak-ng") and shutil.which("sox")), reason="no espeak")
@pytest.mark.long
def test_its_synthesized_audio_is_recognized_by_pocketsphinx(
    spawn, router, session_id, client_config, tmp_path
):
    notices = _teach_through_speech(
        spawn, router, session_id, client_config, tmp_path, ["--engine", "pocketsphinx"]
    )
    understood = [n.meaning for n in notices if n.kind == "understood"]
    # Real recognition errors: most, not all, of what it says is understood.
    judged = [m for m in understood if m in ("good", "excellent", "bad", "terrible")]
    assert len(judged) >= 3, notices

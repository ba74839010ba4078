"""The teacher's web page in a real headless Chromium (Debian's, driven by Playwright) against a
real local session: router, simulator, learner, arbiter, pocketsphinx speech and `voxshape
web`, each its own process. The page draws the map and a moving robot; holding the talk button
with Chromium's fake microphone playing "turn left" makes the learner take the command; a
click on "good" reaches the learner as a credited reward; two pages are two teachers; the
robot's question shows on every page, a click answers it and every page says who did; a wrong
password on a secured session is refused with a clear message.

The page's state is read from `window.voxshape`, never from pixels. Screenshots go to
docs/web/ when VOXSHAPE_SCREENSHOTS=1 (else to the test's temporary folder)."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import time
import uuid
import wave
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ROOT, VOXSHAPE, bus_args, free_port, wait_for_port
from voxshape.launcher import LoopbackSession, router_command
from voxshape.protocol import (
    CreditedFeedback,
    HelpRequest,
    TeachingStats,
    load_vocabulary,
    robot_key,
)
from voxshape.runtime import BusConfig, Input, Node
from voxshape.runtime.audio import read_wav

CHROMIUM = Path("/usr/bin/chromium")
sync_api = pytest.importorskip("playwright.sync_api", reason="Playwright is a dev dependency")
pytestmark = [
    pytest.mark.skipif(
        not CHROMIUM.exists(),
        reason="Debian's chromium is missing (/usr/bin/chromium): `make test` installs it "
        "(deploy/apt-packages-test.txt); no browser is ever downloaded",
    ),
    pytest.mark.timeout(240),
    pytest.mark.xdist_group("web_page"),  # one worker of a parallel run: one session for all
]

FIXTURES = ROOT / "tests" / "fixtures" / "speech"
SPOKEN = FIXTURES / "en-voc-turn-left-kal-diphone.wav"
PAD_S = (0.3, 0.7)  # silence around the words: the fake microphone loops its file
SHOTS = ROOT / "docs" / "web"
MAKING_SCREENSHOTS = os.environ.get("VOXSHAPE_SCREENSHOTS") == "1"
BROWSER_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--use-fake-ui-for-media-stream",
    "--use-fake-device-for-media-stream",
]
WAIT_MS = 20_000  # any one thing the page waits for
SECURED_ACCESS = """
[users]
logger = { role = "admin" }
web = { role = "observer" }
ana = { role = "teacher" }
"""


class Processes:
    """Child processes of a module's session, each ended by its pid."""

    def __init__(self) -> None:
        self.children: list[subprocess.Popen] = []

    def start(self, argv: list[str], cwd: Path) -> subprocess.Popen:
        proc = subprocess.Popen(
            argv, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
        )
        self.children.append(proc)
        return proc

    def stop(self) -> None:
        for proc in reversed(self.children):
            if proc.poll() is None:
                os.kill(proc.pid, signal.SIGTERM)
        for proc in self.children:
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                os.kill(proc.pid, signal.SIGKILL)
                proc.wait(5)


@dataclass
class PageSession:
    """The module's open session: its id, the page's address, the LoopbackSession."""

    id: str
    url: str
    loopback: LoopbackSession

    def node_config(self, name: str) -> BusConfig:
        return self.loopback.client_config(name, connect_timeout=5.0)


def start_web(procs: Processes, cwd: Path, bus: list[str]) -> str:
    port = free_port()
    procs.start([VOXSHAPE, "web", *bus, "--port", str(port), "--task", "1"], cwd)
    wait_for_port(port, timeout=30)
    return f"http://127.0.0.1:{port}/"


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Iterator[PageSession]:
    """An open session: router, arbiter, pocketsphinx speech, a learner and the simulator for
    r1 (5x real time: episodes end within 12 s), and the page's gateway."""
    cwd = tmp_path_factory.mktemp("session")
    port = free_port()
    variables = {"VOXSHAPE_TASK": "1", "VOXSHAPE_WEB_PORT": str(port)}
    # it asks no questions of its own: the test's robot asks (one open a robot)
    learner = ["--robot", "r1", "--seed", "1", "--set", "ask.per_robot_minute=0"]
    sim = ["--robot", "r1", "--rtf", "5", "--seed", "1"]
    with LoopbackSession(
        f"w{uuid.uuid4().hex[:10]}", variables=variables, logs=cwd / "logs", cwd=cwd
    ) as loopback:
        loopback.add(
            *(loopback.service(name) for name in ("arbiter", "speech", "web")),
            loopback.service("learner", *learner),
        )
        wait_for_port(port, timeout=30)
        time.sleep(0.5)  # their subscriptions reach the router with their tokens
        loopback.add(loopback.service("sim", *sim))
        yield PageSession(loopback.session_id, f"http://127.0.0.1:{port}/", loopback)


@pytest.fixture(scope="module")
def spoken_wav(tmp_path_factory) -> Path:
    """The fixture with silence either side, so one pass of the looping fake microphone holds
    the whole phrase."""
    samples = read_wav(SPOKEN)
    pad = [np.zeros(int(s * 16000), np.int16) for s in PAD_S]
    path = tmp_path_factory.mktemp("audio") / "turn-left.wav"
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(16000)
        w.writeframes(np.concatenate([pad[0], samples, pad[1]]).astype("<i2").tobytes())
    return path


@pytest.fixture(scope="module")
def browser(spoken_wav) -> Iterator[object]:
    with sync_api.sync_playwright() as p:
        chromium = p.chromium.launch(
            executable_path=str(CHROMIUM),
            args=[*BROWSER_ARGS, f"--use-file-for-fake-audio-capture={spoken_wav}"],
        )
        try:
            yield chromium
        finally:
            chromium.close()


@pytest.fixture
def open_page(browser):
    """Pages in contexts of their own (as separate browsers), closed after the test."""
    contexts = []

    def open_(url: str, **login: str):
        # the page's policy forbids eval; Playwright's wait_for_function evaluates strings
        context = browser.new_context(viewport={"width": 1280, "height": 900}, bypass_csp=True)
        contexts.append(context)
        page = context.new_page()
        page.errors = []
        page.on("pageerror", lambda e: page.errors.append(str(e)))
        page.goto(url, timeout=WAIT_MS)
        for field, value in login.items():
            page.fill(f"#{field}", value)
        page.click("#login-button")
        return page

    yield open_
    for context in contexts:
        context.close()


def teaching(page) -> None:
    page.wait_for_function("window.voxshape.phase === 'teaching'", timeout=WAIT_MS)


def state(page, expression: str):
    return page.evaluate(f"(s => {expression})(window.voxshape)")


def wait_notice(page, kind: str, meaning: str) -> dict:
    page.wait_for_function(
        f"window.voxshape.notices.some(n => n.kind === {kind!r} && n.meaning === {meaning!r})",
        timeout=WAIT_MS,
    )
    return state(page, f"s.notices.find(n => n.kind === {kind!r} && n.meaning === {meaning!r})")


def wait_feedback(node: Node, teacher: str, timeout: float = 20.0) -> CreditedFeedback:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        event = node.poll(0.1)
        if (
            isinstance(event, Input)
            and isinstance(event.message, CreditedFeedback)
            and teacher in event.message.teachers
        ):
            return event.message
    raise AssertionError(f"no credited feedback from {teacher} within {timeout} s")


def screenshot(page, name: str, tmp_path: Path) -> None:
    path = tmp_path / name
    page.screenshot(path=str(path), full_page=True)
    if MAKING_SCREENSHOTS:
        SHOTS.mkdir(parents=True, exist_ok=True)
        shutil.copy(path, SHOTS / name)


# -- the open session ------------------------------------------------------------------------


def test_the_page_draws_the_map_and_a_moving_robot(session, open_page):
    page = open_page(session.url, teacher="ana")
    teaching(page)
    welcome = state(page, "s.welcome")
    assert welcome["session"] == session.id and welcome["teacher"] == "ana"
    assert len(welcome["map"]["walls"]) >= 4 and welcome["map"]["goal"]["radius"] > 0
    assert {e["meaning"] for e in welcome["vocabulary"]["es"]} >= {"good", "left", "stop"}
    page.wait_for_function("window.voxshape.drawn.r1 !== undefined", timeout=30_000)
    first = state(page, "s.drawn.r1")
    # ten steps on, and moved: a robot pinned against a wall stays put for a while
    page.wait_for_function(
        f"(d => d.step >= {first['step'] + 10} && (d.x !== {first['x']} || "
        f"d.y !== {first['y']} || d.theta !== {first['theta']}))(window.voxshape.drawn.r1)",
        timeout=WAIT_MS,
    )
    later = state(page, "s.drawn.r1")
    assert (later["x"], later["y"], later["theta"]) != (first["x"], first["y"], first["theta"])
    assert (
        0 <= later["x"] <= welcome["map"]["width"] and 0 <= later["y"] <= welcome["map"]["height"]
    )
    frames = state(page, "s.frames.filter(f => f.robot === 'r1').slice(-5)")
    assert all(f["drawn"] >= f["received"] and f["stamp"] > 0 for f in frames)
    # the clock was synced (5 probes at start) and the status line follows the robot
    page.wait_for_function("window.voxshape.clock.replies >= 5", timeout=WAIT_MS)
    assert abs(state(page, "s.clock.offset_ms")) < 1000  # one machine, one clock
    assert "m to the goal" in page.inner_text("#status")
    # the Spanish words replace the English ones on the buttons
    page.click("[data-lang=es]")
    assert page.inner_text("[data-meaning=left]").startswith("izquierda")
    assert page.errors == []


def test_holding_the_button_says_turn_left_to_the_learner(session, open_page, tmp_path):
    with Node("test", session.node_config("observer")) as node:
        node.input("feedback", robot_key(session.id, "r1", "feedback"))
        page = open_page(session.url, teacher="mic")
        teaching(page)
        page.wait_for_function("window.voxshape.obs.r1 !== undefined", timeout=30_000)
        seconds = sum(PAD_S) + 12161 / 16000  # one pass of the fake microphone's file
        page.locator("#talk").hover()
        page.mouse.down()
        page.wait_for_function(
            f"window.voxshape.mic.pressMs >= {seconds * 1000:.0f}", timeout=WAIT_MS
        )
        page.mouse.up()
        assert state(page, "s.mic.error") is None
        feedback = wait_feedback(node, "mic")
    assert (feedback.kind, feedback.command, feedback.teachers) == ("command", "left", ("mic",))
    notice = wait_notice(page, "understood", "left")
    assert notice["heard"] == "turn left" and "understood 'turn left'" in notice["text"]
    assert "understood 'turn left'" in page.inner_text("#notices")
    assert page.errors == []


def test_a_click_on_good_reaches_the_learner_as_a_credited_reward(session, open_page, tmp_path):
    with Node("test", session.node_config("observer")) as node:
        node.input("feedback", robot_key(session.id, "r1", "feedback"))
        page = open_page(session.url, teacher="clicker")
        teaching(page)
        page.wait_for_function("window.voxshape.obs.r1 !== undefined", timeout=30_000)
        page.click("[data-meaning=good]")
        feedback = wait_feedback(node, "clicker")
    assert (feedback.kind, feedback.reward, feedback.teachers) == ("reward", 10.0, ("clicker",))
    notice = wait_notice(page, "understood", "good")
    assert notice["heard"] == "good" and "understood 'good'" in notice["text"]
    # the arrow keys steer: a command, as the page says
    page.keyboard.press("ArrowLeft")
    wait_notice(page, "understood", "left")
    page.wait_for_function("window.voxshape.stats.r1?.teacher?.understood >= 2", timeout=WAIT_MS)
    assert state(page, "s.said.map(x => x.text)") == ["good", "left"]
    if MAKING_SCREENSHOTS:  # a curve on the docs' picture, if one comes (two episodes: ~24 s)
        with contextlib.suppress(sync_api.TimeoutError):
            page.wait_for_function("window.voxshape.curve.r1?.length >= 2", timeout=30_000)
    screenshot(page, "teaching.png", tmp_path)
    assert page.errors == []


def test_two_pages_are_two_teachers(session, open_page):
    with Node("test", session.node_config("observer")) as node:
        node.input("teaching", robot_key(session.id, "r1", "teaching"))
        pages = [open_page(session.url, teacher=t) for t in ("ana", "ben")]
        for page in pages:
            teaching(page)
            page.wait_for_function("window.voxshape.obs.r1 !== undefined", timeout=30_000)
        for page in pages:
            page.keyboard.press("g")
        heard: set[str] = set()
        deadline = time.monotonic() + 20.0
        while not {"ana", "ben"} <= heard and time.monotonic() < deadline:
            event = node.poll(0.1)
            if isinstance(event, Input) and isinstance(event.message, TeachingStats):
                heard |= {t.teacher for t in event.message.teachers if t.understood}
    assert {"ana", "ben"} <= heard, heard
    for page in pages:
        page.wait_for_function("window.voxshape.stats.r1?.teachers >= 2", timeout=WAIT_MS)
        assert page.errors == []


def asked(page, question: str) -> None:
    page.wait_for_function(
        f"window.voxshape.questions.open.r1?.question?.question === {question!r}", timeout=WAIT_MS
    )


def marked(page, questions: list[str]) -> None:
    """The map marks these questions (ids) where they were asked, and no other."""
    ids = "JSON.stringify(window.voxshape.marked.map(m => m.question))"
    page.wait_for_function(f"{ids} === '{json.dumps(questions)}'", timeout=WAIT_MS)


def answered_then_cleared(pages: list, teacher: str, meaning: str) -> None:
    """Every page says who answered, then clears the question a few seconds on."""
    for page in pages:
        page.wait_for_function(
            f"window.voxshape.questions.open.r1?.answer?.teacher === {teacher!r}", timeout=WAIT_MS
        )
        assert f"answered by {teacher}: {meaning}" in page.inner_text("#question")
    for page in pages:
        page.wait_for_function("window.voxshape.questions.open.r1 === undefined", timeout=8000)
        assert page.inner_text("#question").strip() == ""


def test_the_robots_question_shows_on_every_page_and_a_click_answers_it(
    session, open_page, tmp_path
):
    """The test is r1's learner asking; the arbiter takes the first command said within 6 s
    as the answer. One page reads questions aloud (chosen, and remembered), the other answers
    with a click; both say who answered, and clear the question after a few seconds, or
    after ~10 s without an answer."""
    with Node("learner", session.node_config("asker")) as node:
        node.input("feedback", robot_key(session.id, "r1", "feedback"))
        help_ = node.output("help", robot_key(session.id, "r1", "help"))
        pages = [open_page(session.url, teacher=t) for t in ("listener", "answerer")]
        for page in pages:
            teaching(page)
            page.wait_for_function("window.voxshape.obs.r1 !== undefined", timeout=30_000)
        listener, answerer = pages
        assert not listener.is_checked("#speak-questions")  # off by default
        listener.check("#speak-questions")
        assert state(listener, "localStorage.getItem('voxshape.speakQuestions')") == "1"
        obs = state(listener, "s.obs.r1")
        question = HelpRequest(
            robot="r1",
            episode=obs["episode"],
            step=obs["step"],
            reason="stuck",
            detail="stuck for 10 s",
            x=obs["x"],
            y=obs["y"],
        )
        help_.put(question)
        for page in pages:
            asked(page, question.id)
            assert "r1 asks: which way? stuck for 10 s" in page.inner_text("#question")
            assert page.get_attribute("#question", "aria-live") == "assertive"
            marked(page, [question.id])  # and the map marks where it was asked
            (mark,) = state(page, "s.marked")
            assert (mark["x"], mark["y"]) == pytest.approx((question.x, question.y), abs=1e-4)
        # a chime each (the click on Join lets a page play sound), read aloud where chosen
        chimed = "[s.questions.chimes, s.questions.played, s.questions.spoken]"
        assert state(listener, chimed) == [1, 1, 1]
        assert state(answerer, chimed) == [1, 1, 0]
        screenshot(answerer, "question.png", tmp_path)
        # the hint names the answers in the words of the page's language
        answerer.click(".lang button[data-lang=es]")
        left, right, forward = (
            load_vocabulary().meanings[m].phrases["es"][0] for m in ("left", "right", "forward")
        )
        hint = f"say or click {left}, {right} or {forward}"
        answerer.wait_for_function(
            f"document.querySelector('#question').innerText.includes({hint!r})", timeout=WAIT_MS
        )
        answerer.click(".lang button[data-lang=en]")
        answerer.click("[data-meaning=left]")
        feedback = wait_feedback(node, "answerer")
        assert (feedback.kind, feedback.command) == ("command", "left")
        assert [(c.step, c.weight) for c in feedback.credits] == [(question.step, 1.0)]
        answered_then_cleared(pages, "answerer", "left")
        marked(answerer, [])
        assert "question" in wait_notice(answerer, "understood", "left")["text"]
        # a question nobody answers clears too (~10 s; shortened here)
        state(listener, "s.questions.unanswered_ms = 1000")
        again = replace(question, id=uuid.uuid4().hex, step=obs["step"] + 1)
        help_.put(again)
        asked(listener, again.id)
        listener.wait_for_function("window.voxshape.questions.open.r1 === undefined", timeout=5000)
        assert state(listener, "s.questions.answers.length") == 1
    for page in pages:
        assert page.errors == []


# -- a secured session -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def secured(tmp_path_factory) -> Iterator[tuple[str, dict[str, str]]]:
    """A router with passwords and access control, and the gateway as its observer user; the
    page's address and the users' passwords."""
    from voxshape.deploy.access import load_access, load_credentials
    from voxshape.deploy.certs import make_all

    folder = tmp_path_factory.mktemp("secrets")
    (folder / "access.toml").write_text(SECURED_ACCESS)
    make_all(folder, load_access(folder / "access.toml"))
    port = free_port()
    router = f"tcp/127.0.0.1:{port}"
    procs = Processes()
    secrets = ("--secrets", str(folder))
    try:
        procs.start(
            router_command(
                *("--session", "locked", "--node", "router", *secrets),
                *("--access", str(folder / "access.toml"), "--listen", router),
            ),
            folder,
        )
        wait_for_port(port)
        bus = [*bus_args(router, "locked", "web"), "--user", "web", *secrets]
        bus += ["--access", str(folder / "access.toml")]  # the router's: it checks at start
        yield start_web(procs, folder, bus), load_credentials(folder / "credentials")
    finally:
        procs.stop()


def test_a_wrong_password_is_refused_with_a_clear_message(secured, open_page, tmp_path):
    url, passwords = secured
    page = open_page(url, user="ana", password="not-her-password")
    page.wait_for_function("window.voxshape.refused !== null", timeout=WAIT_MS)
    reason = state(page, "s.refused")
    assert "wrong user name or password" in reason, reason  # the same for every failure
    assert page.is_visible("#refused") and "password" in page.inner_text("#refused")
    assert not page.is_visible("#teach")
    screenshot(page, "refused.png", tmp_path)
    # her own password opens the session, as its user: the teacher id is the user name
    page = open_page(url, user="ana", password=passwords["ana"])
    teaching(page)
    assert state(page, "[s.teacher, s.secured]") == ["ana", True]

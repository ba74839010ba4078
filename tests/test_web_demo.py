"""`voxshape demo --web` lasts until its person ends it: once the robot has learnt, the page
says so and what may come next, a word pressed on the page is still understood, and Ctrl-C
ends the demo with its closing lines. Before, the demo ended itself at convergence and the
page said "disconnected: the server is stopping".

No time limit is left to wait out: a web demo's watch is never done, whatever the episodes
(`test_a_web_demos_watch_is_never_done`), so a word pressed after convergence shows it is
teachable however long after."""

from __future__ import annotations

import os
import re
import signal
import subprocess

import pytest

from tests.conftest import VOXSHAPE, free_port, read_until
from tests.test_demo import ended, watch
from tests.test_web_page import BROWSER_ARGS, CHROMIUM, WAIT_MS, state, teaching, wait_notice

sync_api = pytest.importorskip("playwright.sync_api", reason="Playwright is a test dependency")


def test_a_web_demos_watch_is_never_done():
    """Neither convergence nor the episode bound ends a demo a person teaches."""
    progress = watch(3, "--web")
    for n, steps in enumerate([2000, 150, 160, 170]):
        progress.on_episode(ended(n, steps), now=0.0)
    assert progress.convergence.converged and not progress.done
    for n in range(4, 1000):  # long after: its episodes go on being shown
        progress.on_episode(ended(n, 150), now=float(n))
    assert not progress.done and len(progress.episodes) == 1000
    assert progress.learnt().episodes == 4  # what the pages were told


@pytest.mark.skipif(not CHROMIUM.exists(), reason="Debian's chromium is missing")
@pytest.mark.timeout(400)
@pytest.mark.long
@pytest.mark.xdist_group("sessions")  # as tests/test_session_end.py's
def test_the_web_demo_goes_on_after_the_robot_learnt(spawn, session_id, tmp_path):
    web_port = free_port()
    env = {**os.environ, "VOXSHAPE_SESSION": session_id, "VOXSHAPE_WEB_PORT": str(web_port)}
    argv = [VOXSHAPE, "demo", "--web", "--sim-teacher", "--speech", "mock", "--rtf", "20"]
    demo = spawn(
        [*argv, "--port", str(free_port())],
        env=env,
        text=True,
        stderr=subprocess.STDOUT,
        cwd=tmp_path,
    )
    seen: list[str] = []
    read_until(demo, r"teach it in a browser: ", timeout=120, seen=seen)
    read_until(demo, r"r1 has learnt it: \d+ episodes", timeout=240, seen=seen)
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=BROWSER_ARGS)
        page = browser.new_page(bypass_csp=True)
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(f"http://127.0.0.1:{web_port}/", timeout=WAIT_MS)
        page.fill("#teacher", "ana")
        page.click("#login-button")
        teaching(page)
        page.wait_for_function("window.voxshape.learnt.r1 !== undefined", timeout=WAIT_MS)
        learnt = state(page, "s.learnt.r1")
        assert page.is_visible("#learnt")
        assert f"r1 has learnt task 1 in {learnt['episodes']} episode" in page.inner_text("#learnt")
        assert "voxshape demo --web --task 2" in page.inner_text("#learnt")  # another room
        page.wait_for_function(
            f"(window.voxshape.episodes.r1?.episode ?? 0) > {learnt['episode'] + 1}",
            timeout=WAIT_MS,
        )  # episodes go on after it
        page.click("[data-meaning=left]")  # a word pressed after convergence
        notice = wait_notice(page, "understood", "left")
        assert "understood 'left'" in notice["text"]
        assert state(page, "s.phase") == "teaching" and errors == []
        browser.close()
    assert demo.poll() is None
    demo.send_signal(signal.SIGINT)
    out, _ = demo.communicate(timeout=120)
    assert demo.returncode == 0, out[-3000:]
    closing = re.search(r"The robot learnt task 1 in (\d+) episodes .* It went on for", out)
    assert closing and int(closing.group(1)) == learnt["episodes"], out[-3000:]

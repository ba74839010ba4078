"""The web page's latencies and cost, in Debian's headless Chromium against a real local
session (router, learner, simulator, pocketsphinx speech, arbiter, `voxshape web`):

- an observation published -> its frame drawn in the page, p50 and p99: the page's
  performance.now() when it drew the frame, on the gateway's clock through the synced offset,
  against the simulator's wall_time (published) and the gateway's stamp (forwarded); the
  simulator paced at real time, one page open;
- the end of a spoken word at the page -> its utterance on the bus: Chromium's fake microphone
  plays "turn left" while the talk button is held; the utterance's `end` (the last sample of
  speech, gateway clock) against its arrival at a node of this process;
- the simulator's step rate in lockstep (as fast as the learner answers) with no page, then
  with two pages open, and their ratio.

    .venv/bin/python benchmarks/web.py [--seconds 15] [--words 5]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
import uuid
import wave
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.common import spread  # noqa: E402
from voxshape.launcher import LoopbackSession  # noqa: E402
from voxshape.protocol import Observation, Utterance  # noqa: E402
from voxshape.runtime import Input, Node, free_loopback_port  # noqa: E402
from voxshape.runtime.audio import read_wav  # noqa: E402
from voxshape.runtime.config import wait_for_loopback_port as wait_for_port  # noqa: E402

CHROMIUM = "/usr/bin/chromium"
SPOKEN = ROOT / "tests" / "fixtures" / "speech" / "en-voc-turn-left-kal-diphone.wav"
PAD_S = (0.3, 0.7)


def padded_wav(folder: Path) -> Path:
    samples = read_wav(SPOKEN)
    pad = [np.zeros(int(s * 16000), np.int16) for s in PAD_S]
    path = folder / "turn-left.wav"
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(16000)
        w.writeframes(np.concatenate([pad[0], samples, pad[1]]).astype("<i2").tobytes())
    return path


def open_page(browser: Any, url: str, teacher: str) -> tuple[Any, Any]:
    context = browser.new_context(viewport={"width": 1280, "height": 900}, bypass_csp=True)
    page = context.new_page()
    page.goto(f"{url}?teacher={teacher}&join=1", timeout=20_000)
    page.wait_for_function("window.voxshape.phase === 'teaching'", timeout=20_000)
    page.wait_for_function("window.voxshape.obs.r1 !== undefined", timeout=30_000)
    page.wait_for_function("window.voxshape.clock.replies >= 5", timeout=20_000)
    return context, page


def draw_latency(page: Any, seconds: float) -> dict[str, list[float]]:
    """Milliseconds from publication (wall_time) and from the gateway's stamp to the frame."""
    page.evaluate("() => { window.voxshape.frames.length = 0; }")
    time.sleep(seconds)
    frames, origin, offset = page.evaluate(
        "() => [window.voxshape.frames, performance.timeOrigin, window.voxshape.clock.offset_ms]"
    )
    drawn = [origin + f["drawn"] + offset for f in frames if f["robot"] == "r1"]
    rows = [f for f in frames if f["robot"] == "r1"]
    return {
        "published": [d - f["wall_time"] for d, f in zip(drawn, rows, strict=True)],
        "forwarded": [d - f["stamp"] for d, f in zip(drawn, rows, strict=True)],
    }


def spoken_words(page: Any, node: Node, words: int) -> list[float]:
    """Seconds from the end of speech to the utterance arriving, one per press."""
    seconds = sum(PAD_S) + len(read_wav(SPOKEN)) / 16000
    delays = []
    for _ in range(words):
        page.locator("#talk").hover()
        page.mouse.down()
        page.wait_for_function(
            f"window.voxshape.mic.pressMs >= {seconds * 1000:.0f}", timeout=20_000
        )
        page.mouse.up()
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            event = node.poll(0.02)
            if isinstance(event, Input) and isinstance(event.message, Utterance):
                delays.append(time.time() - event.message.end)
                break
        time.sleep(1.2)  # the arbiter's rate limit, and a pause between words
    return delays


def step_rate(node: Node, seconds: float) -> float:
    """Observations a second on the bus."""
    steps, start = 0, time.monotonic()
    while time.monotonic() - start < seconds:
        event = node.poll(0.05)
        if isinstance(event, Input) and isinstance(event.message, Observation):
            steps += 1
    return steps / (time.monotonic() - start)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=15.0, help="per measurement")
    parser.add_argument("--words", type=int, default=5, help="presses of the talk button")
    args = parser.parse_args()
    if not Path(CHROMIUM).exists():
        print(f"needs Debian's chromium at {CHROMIUM} (apt-get install chromium)")
        return 2
    from playwright.sync_api import sync_playwright

    port = free_loopback_port()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        with LoopbackSession(
            f"bench{uuid.uuid4().hex[:8]}",
            variables={"VOXSHAPE_WEB_PORT": str(port)},
            logs=folder / "logs",
            cwd=folder,
        ) as session:
            return measure(session, padded_wav(folder), port, args, sync_playwright)


def measure(
    session: LoopbackSession, wav: Path, port: int, args: argparse.Namespace, sync_playwright: Any
) -> int:
    """The session's services, the page's latencies, then the simulator's step rates."""
    session.add(
        session.service("learner", "--robot", "r1", "--seed", "1"),
        *(session.service(name) for name in ("arbiter", "speech", "web")),
        session.service("sim", "--robot", "r1", "--rtf", "1", "--seed", "1"),
    )
    wait_for_port(port, timeout=30.0)
    url = f"http://127.0.0.1:{port}/"
    time.sleep(0.5)  # their subscriptions reach the router with their tokens
    browser_args = [
        *("--no-sandbox", "--disable-gpu", "--disable-background-networking"),
        *("--disable-component-update", "--disable-sync", "--no-first-run"),
        *("--use-fake-ui-for-media-stream", "--use-fake-device-for-media-stream"),
        f"--use-file-for-fake-audio-capture={wav}",
    ]
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=browser_args)
        page_latencies(browser, url, session, args)
        alone, watched = step_rates(browser, url, session, args.seconds)
        browser.close()
    print(
        f"simulator steps a second in lockstep: {alone:.0f} with no page, {watched:.0f} with "
        f"two pages open: ratio {watched / alone:.2f}"
    )
    return 0


def page_latencies(
    browser: Any, url: str, session: LoopbackSession, args: argparse.Namespace
) -> None:
    """Prints observation -> frame drawn, and the end of a spoken word -> its utterance."""
    context, page = open_page(browser, url, "bench")
    latency = draw_latency(page, args.seconds)
    with Node("bench", session.client_config("words")) as node:
        node.subscribe("utterance", "bench")
        time.sleep(0.5)
        words = spoken_words(page, node, args.words)
    context.close()
    print(f"obs -> frame drawn, simulator paced at real time, one page, {args.seconds:g} s:")
    for name, values in latency.items():
        print(f"  from {name:9}: {spread(values)}")
    heard = f"{len(words)} of {args.words} presses heard"
    if words:
        median, worst = statistics.median(words) * 1000, max(words) * 1000
        print(
            f"end of a spoken word -> utterance on the bus: median {median:.0f} ms, "
            f"max {worst:.0f} ms ({heard})"
        )
    else:
        print(f"end of a spoken word -> utterance on the bus: {heard}")


def step_rates(
    browser: Any, url: str, session: LoopbackSession, seconds: float
) -> tuple[float, float]:
    """The simulator's steps a second in lockstep with no page open, then with two."""
    session.end("sim")
    lockstep = ("--robot", "r1", "--clock", "lockstep", "--seed", "1")
    session.add(session.service("sim", *lockstep, named="sim-lockstep"))
    with Node("bench", session.client_config("steps")) as node:
        node.subscribe("obs", "r1")
        time.sleep(3.0)  # the learner and the simulator find their pace
        alone = step_rate(node, seconds)
        pages = [open_page(browser, url, f"watch{i}") for i in range(2)]
        watched = step_rate(node, seconds)
        for context, _ in pages:
            context.close()
    return alone, watched


if __name__ == "__main__":
    sys.exit(main())

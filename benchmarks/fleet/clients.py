"""The fleet's teachers: the simulated people and the browsers.

A simulated person is `voxshape sim-teacher` (its default profile). A browser is a WebSocket
client of the page's gateway speaking the page's own protocol (voxshape/services/web/static/
net.js and app.js): log in, clock probes, `watch` its robot, read every map frame, press a
word button now and then. The browsers run in processes of the harness (`python -m
benchmarks.fleet --browser-client`), at most BROWSERS_PER_PROCESS in each, each writing what
it saw to a JSON file when it ends.
"""

from __future__ import annotations

import argparse
import array
import asyncio
import json
import random
import signal
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

BROWSERS_PER_PROCESS = 10
LOGINS_AT_ONCE = 4  # the gateway lets 8 sockets an address wait to log in
# The page's word buttons (voxshape/services/web/static/words.js)
MEANINGS = ("excellent", "good", "goal", "terrible", "bad", "stop", "forward", "left", "back")
MEANINGS += ("right",)


# -- starting them ----------------------------------------------------------------------------
def sim_teacher_command(teacher: str, robot: str, seed: int) -> list[str]:
    """A simulated person, `teacher`, teaching `robot`."""
    return ["voxshape", "sim-teacher", "--robot", robot, "--teacher", teacher, "--seed", str(seed)]


def browser_processes(
    browsers: list[tuple[str, str]], web_port: int, workdir: Path, word_every: float, seed: int
) -> list[tuple[str, list[str]]]:
    """The processes for the (teacher, robot) browsers, BROWSERS_PER_PROCESS in each: name
    and argv of each (run with the checkout on their PYTHONPATH: common.checkout_environment())."""
    out = []
    for i in range(0, len(browsers), BROWSERS_PER_PROCESS):
        group = browsers[i : i + BROWSERS_PER_PROCESS]
        name = f"browsers-{i // BROWSERS_PER_PROCESS + 1}"
        argv = [sys.executable, "-m", "benchmarks.fleet", "--browser-client"]
        argv += ["--url", f"ws://127.0.0.1:{web_port}/ws"]
        argv += ["--assign", ",".join(f"{t}={r}" for t, r in group)]
        argv += ["--word-every", f"{word_every:g}", "--seed", str(seed + i)]
        argv += ["--out", str(workdir / f"{name}.json")]
        out.append((name, argv))
    return out


# -- the browsers (a process of the harness) --------------------------------------------------
@dataclass
class BrowserRecord:
    said: list[list] = field(default_factory=list)  # [sent s, teacher, robot, text]
    notices: list[list] = field(default_factory=list)  # [at s, teacher, utterance, kind, late]
    frames: array.array = field(default_factory=lambda: array.array("d"))  # at, age, hop
    frames_by: Counter = field(default_factory=Counter)
    welcomed: list[str] = field(default_factory=list)
    closed: dict[str, str] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)


def browser_client(args: argparse.Namespace) -> int:
    """`--browser-client`: the browsers of `--assign` until SIGTERM; writes `--out`."""
    rec = BrowserRecord()
    asyncio.run(_browsers(args, rec))
    frames = rec.frames.tolist()
    Path(args.out).write_text(
        json.dumps(
            {
                "said": rec.said,
                "notices": rec.notices,
                "frames": [frames[i : i + 3] for i in range(0, len(frames), 3)],
                "frames_by": dict(rec.frames_by),
                "welcomed": rec.welcomed,
                "closed": rec.closed,
                "errors": rec.errors[:50],
            }
        )
    )
    return 0


async def _browsers(args: argparse.Namespace, rec: BrowserRecord) -> None:
    import aiohttp

    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for s in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(s, stop.set)
    logins = asyncio.Semaphore(LOGINS_AT_ONCE)
    origin = args.url.replace("ws://", "http://").rsplit("/", 1)[0]
    async with aiohttp.ClientSession() as http:
        tasks = []
        for i, pair in enumerate(args.assign.split(",")):
            teacher, robot = pair.split("=")
            rng = random.Random(args.seed * 1000 + i)
            page = Page(http, args.url, origin, teacher, robot, args.word_every, rng, rec)
            tasks.append(asyncio.create_task(page.run(logins)))
        await stop.wait()
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


class Page:
    """One teacher's page, as app.js and net.js drive the socket (no drawing)."""

    def __init__(
        self,
        http: Any,
        url: str,
        origin: str,
        teacher: str,
        robot: str,
        word_every: float,
        rng: random.Random,
        rec: BrowserRecord,
    ) -> None:
        self.http, self.url, self.origin = http, url, origin
        self.teacher, self.robot, self.word_every = teacher, robot, word_every
        self.rng, self.rec = rng, rec
        self.own: dict[str, float] | None = None  # the best clock exchange: offset, rtt
        self.ws: Any = None

    async def run(self, logins: asyncio.Semaphore) -> None:
        welcome = await self._login(logins)
        if welcome is None:
            return
        self.rec.welcomed.append(self.teacher)
        vocabulary = welcome.get("vocabulary") or {}
        phrases = {e["meaning"]: e["phrase"] for e in reversed(vocabulary.get("en", []))}
        await self._send({"type": "watch", "robot": self.robot})
        others = [
            asyncio.create_task(self._clock_sync()),
            asyncio.create_task(self._speak(phrases)),
        ]
        try:
            await self._read()
        finally:
            for task in others:
                task.cancel()
            await self.ws.close()

    async def _login(self, logins: asyncio.Semaphore) -> dict[str, Any] | None:
        """Connects and logs in (an open session's: no user, no password); the welcome, or
        None, noted in `closed`."""
        import aiohttp

        try:
            async with logins:
                self.ws = await self.http.ws_connect(self.url, origin=self.origin)
                login = {"type": "login", "teacher": self.teacher, "user": None}
                await self._send({**login, "password": None})  # an open session's
                first = await self.ws.receive(timeout=60)
        except (OSError, aiohttp.ClientError, TimeoutError) as e:
            self.rec.closed[self.teacher] = f"could not log in: {e!r}"
            return None
        welcome = json.loads(first.data) if first.type == aiohttp.WSMsgType.TEXT else {}
        if welcome.get("type") != "welcome":
            self.rec.closed[self.teacher] = f"not welcomed: {str(first.data)[:200]}"
            return None
        return welcome

    async def _send(self, msg: dict[str, Any]) -> bool:
        if self.ws.closed:
            return False
        await self.ws.send_str(json.dumps(msg))
        return True

    async def _clock_sync(self) -> None:
        """net.js: 5 probes 100 ms apart, then one every 30 s, each with our best exchange."""
        for i in range(5):
            await asyncio.sleep(0.0 if i == 0 else 0.1)
            await self._send({"type": "clock", "t0": time.time() * 1000, **(self.own or {})})
        while True:
            await asyncio.sleep(30.0)
            await self._send({"type": "clock", "t0": time.time() * 1000, **(self.own or {})})

    async def _speak(self, phrases: dict[str, str]) -> None:
        """A word button pressed every `word_every` s on average (the first within one)."""
        await asyncio.sleep(self.rng.uniform(0, self.word_every))
        while True:
            meaning = self.rng.choice(MEANINGS)
            text = phrases.get(meaning, meaning)  # words.js phraseFor: the first phrase
            now = time.time()
            msg = {"type": "say", "robot": self.robot, "text": text, "language": "en"}
            if await self._send({**msg, "onset": now * 1000}):
                self.rec.said.append([now, self.teacher, self.robot, text])
            await asyncio.sleep(self.rng.expovariate(1.0 / self.word_every))

    async def _read(self) -> None:
        import aiohttp

        rec = self.rec
        async for msg in self.ws:
            now = time.time()
            if msg.type != aiohttp.WSMsgType.TEXT:
                continue
            data: str = msg.data
            if data.startswith('{"type": "obs"'):  # the frame's tail, without parsing it all
                i = data.rfind('"stamp": ')
                k = data.rfind('"wall_time": ')
                stamp = float(data[i + 9 : data.index(",", i)])
                wall = float(data[k + 13 : data.rindex("}")])
                rec.frames.extend((now, now * 1000 - wall, now * 1000 - stamp))
                rec.frames_by[self.teacher] += 1
                continue
            self._on(json.loads(data), now)
        rec.closed[self.teacher] = f"closed ({self.ws.close_code})"

    def _on(self, m: dict[str, Any], now: float) -> None:
        """A frame other than a map frame: a clock reply, a notice or an error."""
        kind = m.get("type")
        if kind == "clock":  # net.js _clockReply
            t3 = now * 1000
            rtt = t3 - m["t0"]
            if self.own is None or rtt <= self.own["rtt_ms"]:
                self.own = {"offset_ms": m["t1"] - (m["t0"] + t3) / 2, "rtt_ms": rtt}
        elif kind == "notice":
            row = [now, self.teacher, m.get("utterance"), m.get("kind"), m.get("late")]
            self.rec.notices.append(row)
        elif kind == "error":
            self.rec.errors.append(f"{self.teacher}: {m.get('text')}")

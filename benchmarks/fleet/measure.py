"""The fleet's figures: the window's CPU reading, a point's figures and its limit.

`measure()` waits out the warm-up and the window and reads the CPU and memory of every
process; `results()` makes a point's figures of that reading, of what the probe saw
(benchmarks/probe.py's Window) and of the browsers' records; `limit()` names what ran out
first. Each latency's percentiles come with their sample count (`..._n`): a p99 of fewer than
100 samples is their maximum.
"""

from __future__ import annotations

import argparse
import bisect
import contextlib
import os
import time
from collections import Counter, defaultdict
from typing import TYPE_CHECKING, Any

import psutil

from benchmarks.common import percentile
from voxshape.services.speech.transcriber import heard_id

if TYPE_CHECKING:
    from benchmarks.fleet.session import Fleet
    from benchmarks.probe import Window

RATE_HZ = 10.0  # the robots' control rate at real time
ACTION_VALID_S = 0.5  # voxshape sim, paced: an action older than this stops the robot
SETTLE_S = 3.0  # words said in the window's last seconds are not counted
SATURATED = 85.0  # % of one core: a Python process (one GIL) is out of CPU
MACHINE_SATURATED = 0.9  # share of all cores
# What counts as late, for naming what broke
LATE = {"obs_to_action_p99_ms": 100.0, "frame_age_p99_ms": 250.0, "word_to_feedback_p99_ms": 1000}

# A word: (teacher kind, said at, understood at or None, feedback at or None)
Word = tuple[str, float, float | None, float | None]


def pct(values: list[float], q: float) -> float | None:
    """The nearest-rank percentile, in tenths (None: no values)."""
    found = percentile(values, q)
    return None if found is None else round(found, 1)


def latency(name: str, values: list[float]) -> dict[str, Any]:
    """`name`_p50_ms and `name`_p99_ms of `values` (ms), and `name`_n, how many there were:
    the p99 of fewer than 100 is their maximum."""
    return {
        f"{name}_p50_ms": pct(values, 50),
        f"{name}_p99_ms": pct(values, 99),
        f"{name}_n": len(values),
    }


# -- the CPU reading ----------------------------------------------------------------------------
class CpuMeter:
    """CPU seconds of each process and of the machine between two readings."""

    def __init__(self, pids: dict[str, int]) -> None:
        self.procs = {}
        for name, pid in {**pids, "harness": os.getpid()}.items():
            with contextlib.suppress(psutil.Error):
                self.procs[name] = psutil.Process(pid)
        self.t0 = time.monotonic()
        self.before = {name: _cpu(p) for name, p in self.procs.items()}
        self.machine0 = psutil.cpu_times()

    def read(self) -> tuple[dict[str, float], dict[str, float], dict[str, float]]:
        """CPU % of one core and RSS MB per process; the machine's busy, steal and other %."""
        elapsed = time.monotonic() - self.t0
        cpu, rss = {}, {}
        for name, p in self.procs.items():
            with contextlib.suppress(psutil.Error):
                cpu[name] = 100.0 * (_cpu(p) - self.before[name]) / elapsed
                rss[name] = p.memory_info().rss / 2**20
        m0, m1 = self.machine0, psutil.cpu_times()
        total = sum(m1) - sum(m0)
        idle = (m1.idle - m0.idle) + (getattr(m1, "iowait", 0) - getattr(m0, "iowait", 0))
        steal = getattr(m1, "steal", 0) - getattr(m0, "steal", 0)
        cores = psutil.cpu_count() or 1
        busy = 100.0 * cores * (total - idle - steal) / total if total > 0 else 0.0
        machine = {
            "cores": cores,
            "busy_percent": round(busy, 1),  # of one core: 200 is all of two
            "steal_percent": round(100.0 * cores * steal / total, 1) if total > 0 else 0.0,
            "others_percent": round(max(0.0, busy - sum(cpu.values())), 1),
            "load_1min": round(os.getloadavg()[0], 2),
        }
        return cpu, rss, machine


def _cpu(p: psutil.Process) -> float:
    t = p.cpu_times()
    return t.user + t.system


def measure(fleet: Fleet, args: argparse.Namespace) -> tuple[dict, CpuMeter, float, float]:
    """Warm-up, then the window; the CPU reading, and the window's wall clock bounds."""
    time.sleep(args.warmup)
    meter = CpuMeter(fleet.pids())
    t0 = time.time()
    deadline = time.monotonic() + args.seconds
    while time.monotonic() < deadline:
        fleet.session.check_children()  # ServiceDied if one ended, with the end of its log
        time.sleep(min(0.5, max(0.0, deadline - time.monotonic())))
    cpu, rss, machine = meter.read()
    return {"cpu": cpu, "rss": rss, "machine": machine}, meter, t0, time.time()


# -- a point's figures --------------------------------------------------------------------------
def results(
    fleet: Fleet, reading: dict, t0: float, t1: float, browsers_seen: list[dict]
) -> dict[str, Any]:
    """One point's figures, from the probe, the browsers' records and the CPU reading."""
    window = fleet.probe.window(fleet.robots, t0, t1)
    count_until = t1 - SETTLE_S
    refused: Counter[str] = Counter()
    words = _sim_words(window, t0, count_until, refused)
    frames: list[list[float]] = []
    closed: dict[str, str] = {}
    errors: list[str] = []
    for record in browsers_seen:
        words += _browser_words(record, count_until, t0, window.feedback_at, refused)
        frames += [f for f in record["frames"] if t0 <= f[0] < t1]
        closed.update(record["closed"])
        errors += record["errors"]
    browsers = len(fleet.browsers)
    out: dict[str, Any] = {
        "robots": len(fleet.robots),
        "teachers": len(fleet.sim_teachers) + browsers,
        "sim_teachers": len(fleet.sim_teachers),
        "simulators": len(fleet.sims),
        "browsers": browsers,
        "seconds": round(t1 - t0, 1),
        **_robot_figures(window),
        **_word_figures(words, refused),
        **_frame_figures(frames, browsers, len(fleet.robots), t1 - t0),
        "browsers_closed": closed,
        "browser_errors": errors[:10],
        **_process_figures(reading),
    }
    out["limit"] = limit(out)
    return out


def _robot_figures(window: Window) -> dict[str, Any]:
    """Each robot's step rate (steps over the simulator's wall time), the share of its steps
    that reached the probe, and its steps without a fresh action; observation -> action."""
    rates, received, stale = {}, {}, {}
    for robot, rows in window.obs.items():
        stale[robot] = _without_action(rows, window.actions[robot])
        if len(rows) < 2:
            rates[robot], received[robot] = 0.0, 0.0
            continue
        first, last = min(rows, key=lambda o: o[1]), max(rows, key=lambda o: o[1])
        span = last[2] - first[2]
        rates[robot] = round((last[1] - first[1]) / span, 2) if span > 0 else 0.0
        received[robot] = round(len({o[1] for o in rows}) / (last[1] - first[1] + 1), 4)
    steps = max(1, sum(len(rows) for rows in window.obs.values()))
    return {
        "min_robot_rate_hz": min(rates.values()) if rates else 0.0,
        "mean_robot_rate_hz": round(sum(rates.values()) / len(rates), 2) if rates else 0.0,
        "robot_rates_hz": rates,
        "min_obs_received_share": min(received.values()) if received else 0.0,
        "steps_without_action_share": round(sum(stale.values()) / steps, 4),
        **latency("obs_to_action", window.lags),
    }


def _without_action(rows: list[tuple[float, int, float]], actions: list[float]) -> int:
    """Steps whose robot had no action newer than the simulator's 0.5 s (as the probe saw
    them arrive): the robot stood still, its learner behind."""
    n = 0
    for at, _, _ in rows:
        i = bisect.bisect_right(actions, at)
        n += i == 0 or at - actions[i - 1] > ACTION_VALID_S
    return n


def _sim_words(window: Window, t0: float, count_until: float, refused: Counter[str]) -> list[Word]:
    """The simulated people's words said in [t0, count_until), matched by utterance id; why
    each one not understood was not, counted in `refused`."""
    kinds_of = defaultdict(list)
    for _, n in window.notices:
        kinds_of[n.utterance].append(n.kind)
    words: list[Word] = []
    for said_id, (at, _teacher, _robot) in window.said.items():
        if not t0 <= at < count_until:
            continue
        ids = [heard_id(said_id, i) for i in (0, 1)]
        heard = next((window.understood_at[u] for u in ids if u in window.understood_at), None)
        fed = next((window.feedback_at[u] for u in ids if u in window.feedback_at), None)
        words.append(("sim", at, heard, fed))
        if heard is None:
            kinds = [k for u in ids for k in kinds_of.get(u, [])]
            refused[kinds[0] if kinds else "no notice (or not recognized)"] += 1
    return words


def _browser_words(
    record: dict,
    count_until: float,
    t0: float,
    feedback_at: dict[str, float],
    refused: Counter[str],
) -> list[Word]:
    """A browser's words: each said is matched to the first notice of a new utterance id of
    its teacher, in order (one socket, one worker: the gateway publishes them in order)."""
    said_by, notices_by = defaultdict(list), defaultdict(list)
    for at, teacher, _robot, _text in record["said"]:
        said_by[teacher].append(at)
    for row in record["notices"]:
        notices_by[row[1]].append(row)
    words = []
    for teacher, said in said_by.items():
        ids, understood, kinds = _utterances(notices_by[teacher])
        for i, at in enumerate(sorted(said)):
            if not t0 <= at < count_until:
                continue
            u = ids[i] if i < len(ids) else None
            heard = understood.get(u) if u else None
            words.append(("browser", at, heard, feedback_at.get(u) if u else None))
            if heard is None:
                refused[kinds.get(u, "no notice") if u else "no notice"] += 1
    return words


def _utterances(notices: list[list]) -> tuple[list[str], dict[str, float], dict[str, str]]:
    """Of a browser's notices: the utterance ids in order of their first notice, when each
    was understood, and each one's kind (its first, or the last but "no_answer")."""
    ids: list[str] = []
    understood: dict[str, float] = {}
    kinds: dict[str, str] = {}
    for at, _, utterance, kind, _late in sorted(notices):
        if utterance not in kinds:
            ids.append(utterance)
            kinds[utterance] = kind
        if kind == "understood":
            understood.setdefault(utterance, at)
        elif kind != "no_answer":
            kinds[utterance] = kind
    return ids, understood, kinds


def _word_figures(words: list[Word], refused: Counter[str]) -> dict[str, Any]:
    to_notice = [(h - a) * 1000 for _, a, h, _ in words if h is not None]
    to_feedback = [(f - a) * 1000 for _, a, _, f in words if f is not None]
    return {
        "words_said": len(words),
        "words_understood": sum(1 for w in words if w[2] is not None),
        "words_lost": sum(1 for w in words if w[2] is None),
        "words_not_understood_why": dict(refused),
        **latency("word_to_notice", to_notice),
        **latency("word_to_feedback", to_feedback),
        "words_without_feedback": sum(1 for w in words if w[2] is not None and w[3] is None),
        "words_by_teacher_kind": _by_kind(words),
    }


def _by_kind(words: list[Word]) -> dict[str, dict[str, Any]]:
    """The words of the simulated people and of the browsers apart."""
    by_kind = {}
    for kind in ("sim", "browser"):
        mine = [w for w in words if w[0] == kind]
        by_kind[kind] = {
            "said": len(mine),
            "lost": sum(1 for w in mine if w[2] is None),
            **latency("to_notice", [(w[2] - w[1]) * 1000 for w in mine if w[2]]),
            **latency("to_feedback", [(w[3] - w[1]) * 1000 for w in mine if w[3]]),
        }
    return by_kind


def _frame_figures(
    frames: list[list[float]], browsers: int, robots: int, seconds: float
) -> dict[str, Any]:
    """The page's map frames (at, age, gateway -> page; ms): their age when they reach the
    browser, in two hops, and how many a browser got a second."""
    ages = [f[1] for f in frames]
    hops = [f[2] for f in frames]
    return {
        **latency("frame_age", ages),
        **latency("frame_sim_to_gateway", [f[1] - f[2] for f in frames]),
        **latency("frame_gateway_to_page", hops),
        "frames_per_browser_s": round(len(frames) / browsers / seconds, 1) if browsers else None,
        "frames_expected_per_browser_s": RATE_HZ * robots if browsers else None,
    }


def _process_figures(reading: dict) -> dict[str, Any]:
    cpu, rss = reading["cpu"], reading["rss"]
    return {
        "cpu_percent": _grouped(cpu, sum),
        "cpu_percent_max_sim_teacher": round(
            max((v for k, v in cpu.items() if k.startswith("sim-teacher")), default=0.0), 1
        ),
        "rss_mb": _grouped(rss, sum),
        "machine": reading["machine"],
    }


def _grouped(values: dict[str, float], combine: Any) -> dict[str, float]:
    """Per process, the simulated teachers and the browser processes summed."""
    out: dict[str, list[float]] = defaultdict(list)
    for name, v in values.items():
        key = name
        if name.startswith("sim-teacher"):
            key = "sim-teachers"
        elif name.startswith("browsers"):
            key = "browsers (harness)"
        out[key].append(v)
    return {k: round(combine(v), 1) for k, v in sorted(out.items())}


# -- what ran out -------------------------------------------------------------------------------
def limit(point: dict[str, Any]) -> dict[str, Any]:
    """The first resource out at this point: a process at SATURATED % of a core or more (the
    busiest of them), else the machine's cores; and what showed it."""
    harness = {k: v for k, v in point["cpu_percent"].items() if "harness" in k}
    cpu = {
        k: v for k, v in point["cpu_percent"].items() if k != "sim-teachers" and k not in harness
    }
    if point["sim_teachers"]:
        cpu["sim-teacher (busiest)"] = point["cpu_percent_max_sim_teacher"]
    busiest = max(cpu, key=lambda k: cpu[k])
    machine = point["machine"]
    if cpu[busiest] >= SATURATED:
        what = f"CPU of the {busiest} process ({cpu[busiest]:.0f}% of a core)"
        out = True
    elif machine["busy_percent"] >= MACHINE_SATURATED * 100 * machine["cores"]:
        what = (
            f"the machine's {machine['cores']} cores ({machine['busy_percent']:.0f}% of "
            f"{100 * machine['cores']}, {machine['others_percent']:.0f}% other work); busiest: "
            f"{busiest} at {cpu[busiest]:.0f}%"
        )
        out = True
    else:
        what = f"nothing (busiest: {busiest} at {cpu[busiest]:.0f}% of a core)"
        out = False
    symptoms = _symptoms(point, harness)
    return {"process": busiest, "ran_out": out, "what": what, "symptoms": symptoms}


def _symptoms(point: dict[str, Any], harness: dict[str, float]) -> list[str]:
    """What showed a point behind: a busy harness, slow robots, late figures, lost words,
    closed browsers."""
    symptoms = [
        f"the harness's {k} at {v:.0f}%: what it measures may be its own delay"
        for k, v in harness.items()
        if v >= SATURATED
    ]
    if point["min_robot_rate_hz"] < RATE_HZ * 0.95:
        symptoms.append(f"slowest robot at {point['min_robot_rate_hz']:.2f} Hz")
    if point["steps_without_action_share"] > 0.01:
        share = point["steps_without_action_share"]
        symptoms.append(f"{share:.0%} of steps without a fresh action")
    for name, bound in LATE.items():
        if point.get(name) is not None and point[name] > bound:
            symptoms.append(f"{name} {point[name]:.0f} > {bound:.0f}")
    if point["words_lost"]:
        symptoms.append(f"{point['words_lost']} of {point['words_said']} words not understood")
    if point["browsers_closed"]:
        symptoms.append(f"{len(point['browsers_closed'])} browsers closed")
    return symptoms

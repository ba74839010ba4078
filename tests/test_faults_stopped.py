"""An observer stopped (SIGSTOP) for 10 s, a logger, a web page or a second site's router:
the robot keeps its pace, the words of the stop are credited then, and the logs hold
everything (or a marked gap for per-step messages no longer kept)."""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path
from statistics import median

import pytest

from tests import stopped_observer as so
from tests.conftest import free_port, wait_for_port, wait_present
from tests.faults_support import figures, last_counters
from voxshape.launcher import router_command
from voxshape.runtime import Node


# -- stopped observers ------------------------------------------------------------------------
def check_stopped_observer(name: str, seen: so.Seen, logs: dict[str, Path]) -> None:
    """The robot kept its pace, the words said during the stop were credited then (the
    commands carried out in order), and each log has every word and feedback, and every
    observation or a gap marked for it."""
    pace = {k: [round(v) for v in seen.windows(k)] for k in seen.phases}
    commands = [w for _, w in so.DURING if w in ("left", "right")]
    during = seen.during_stop([*commands, ""])
    held = {site: so.logged(path) for site, path in logs.items()}
    figures(
        f"{name} stopped {so.STOP_S:g} s",
        steps_per_s=pace,
        slowest_window_of_the_stop=min(pace["stopped"]),
        robot_stood_without_an_action=seen.stood,
        pace_before=round(seen.before()),
        feedback_during_stop=len(during),
        teacher_actions=so.in_order(seen.teacher_actions),
        logged={
            site: {
                "utterances": f"{len(set(seen.utterances) & h.utterances)}/{len(seen.utterances)}",
                "feedback": f"{len(set(seen.feedback) & h.feedback)}/{len(seen.feedback)}",
                "obs": len(h.obs_steps),
                "missed_marked": dict(h.missed),
                "obs_unaccounted": h.obs_unaccounted,
            }
            for site, h in held.items()
        },
    )
    # never a window without a step, and its usual pace on the whole: one slow window is a
    # loaded machine's, a stall holds every window of the stop
    assert min(pace["stopped"]) > 0 and median(pace["stopped"]) > seen.before() / 4, pace
    assert len(during) == len(so.DURING), f"credited during the stop: {during}"
    assert so.in_order(seen.teacher_actions)[-len(commands) :] == commands
    for site, h in held.items():
        assert set(seen.utterances) <= h.utterances, site
        assert set(seen.feedback) <= h.feedback, site
        assert not {k: n for k, n in h.missed.items() if k not in ("obs", "action", "learning")}
        assert h.obs_unaccounted == 0, (site, h.missed)


def events_of(run: Path, session_id: str) -> Path:
    return run / "runs" / session_id / "events.msgpack"


def stopped_observer_run(spawn, router, session_id, client_config, run: Path, observer=None):
    """The session of tests/stopped_observer.py with `observer(session)` stopped (default:
    its logger), then ended: what the test's node saw."""
    procs = so.start_session(spawn, router, session_id, run)
    seen = so.Seen()
    with Node("test", client_config("watch")) as node:
        node.watch_presence()
        wait_present(node, {"sim", "learner", "arbiter", "logger", "teach"})
        so.watch(node, session_id)
        stopped = procs["logger"] if observer is None else observer()
        so.stop_for(node, seen, stopped, procs["teach"])
        procs["teach"].stdin.close()
        procs["teach"].wait(30)
        for name in ("sim", "learner", "arbiter", "logger"):
            procs[name].send_signal(signal.SIGTERM)
            assert procs[name].wait(30) == 0, name
    seen.stood = last_counters((run / "sim.log").read_text()).get("stopped_without_action", 0)
    return seen


@pytest.mark.long
def test_a_stopped_logger_never_slows_the_robot_and_logs_everything_after(
    spawn, router, session_id, client_config, tmp_path
):
    """The logger stopped (SIGSTOP) for 10 s: no 0.5 s window of the robot's pace below a
    quarter of its pace before; the words of the stop credited during it; when the logger
    runs again it gets back what it missed, and marks a gap for what is no longer kept."""
    seen = stopped_observer_run(spawn, router, session_id, client_config, tmp_path)
    check_stopped_observer(
        "logger", seen, {"main": tmp_path / "runs" / session_id / "events.msgpack"}
    )


@pytest.mark.long
def test_a_stopped_web_page_never_slows_the_robot(
    spawn, router, session_id, client_config, tmp_path
):
    def web():
        return so.service(spawn, "web", router, session_id, "web", "--port", str(free_port()),
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip

    seen = stopped_observer_run(spawn, router, session_id, client_config, tmp_path, web)
    check_stopped_observer(
        "web page", seen, {"main": tmp_path / "runs" / session_id / "events.msgpack"}
    )


@pytest.mark.long
def test_a_stopped_second_site_router_never_slows_the_robot(
    spawn, router, session_id, client_config, tmp_path
):
    """A second site's router (meshed with the session's) and its own logger: the router
    stopped, the robot keeps its pace and both logs have everything, gaps marked."""
    site2 = tmp_path / "site2"
    site2.mkdir()

    def second_site():
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        argv = router_command(
            "--session", session_id, "--node", "router2", "--listen", endpoint, "--connect", router
        )
        other = spawn(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wait_for_port(int(endpoint.rsplit(":", 1)[1]))
        so.service(spawn, "logger", endpoint, session_id, "logger2", "--serve-port", "0",
                   cwd=site2, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
        time.sleep(3.0)  # the sites meshed, the logger subscribed through both
        return other

    seen = stopped_observer_run(spawn, router, session_id, client_config, tmp_path, second_site)
    time.sleep(3.0)  # the second site's logger catches up before it is stopped
    logs = {"main": events_of(tmp_path, session_id), "site2": events_of(site2, session_id)}
    check_stopped_observer("second site's router", seen, logs)

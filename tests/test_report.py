"""`voxshape report`: episodes and interventions counted one way (to convergence, judged by the
map the session ran on, and in all), a simulator restarting within one log kept apart, and
pictures whose axes stay readable."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from tests.logger_support import LONG_ROOM, scripted_session, write_script
from voxshape.lab.report import load_run, write_report
from voxshape.lab.report.counts import count_episodes
from voxshape.lab.report.pictures import pick_episodes, robust_limits
from voxshape.lab.report.summary import RobotSummary, summarize
from voxshape.protocol import EpisodeEvent, TeachingStats
from voxshape.runtime.settings import write_settings
from voxshape.services.learner.config import LearnerConfig, with_settings
from voxshape.services.logger.eventlog import read_events
from voxshape.services.logger.run import RunDir, RunError, describe_session, write_session_info
from voxshape.world.maps import load_map


@pytest.fixture
def restarted_run(tmp_path):
    """An event log in which the simulator started twice: 3 episodes, then (its episode
    numbers and steps from 0 again) 2 more, the teacher heard in episode 1 of the first and
    episode 0 of the second."""
    run = RunDir(tmp_path / "runs" / "s1")
    write_session_info(run, describe_session("s1", "1", {"task": "1"}))
    first = scripted_session("s1", episodes=3, steps=20, feedback_episode=1)
    second = scripted_session("s1", episodes=2, steps=20, feedback_episode=0)
    both = scripted_session("s1", episodes=0)
    both.messages = first.messages + second.messages
    write_script(run.events, "s1", both)
    return run, first, second


def test_a_simulator_restarting_within_a_log_starts_a_new_run_never_merged(restarted_run):
    run, first, second = restarted_run
    robot = summarize(read_events(run.events).records, "s1").robots["r1"]
    assert robot.runs == 2
    assert [robot.label(e) for e in robot.episodes] == ["1:0", "1:1", "1:2", "2:0", "2:1"]
    assert [e.position for e in robot.episodes] == [0, 1, 2, 3, 4]
    returns = [first.returns[n] for n in range(3)] + [second.returns[n] for n in range(2)]
    assert [e.env_return for e in robot.ended] == returns
    # steps continue across the restart: the second run's follow the first's
    assert len(robot.steps) == first.observations + second.observations
    assert np.all(np.diff(robot.steps) > 0)
    offset = first.observations  # the first run's steps are 0..observations-1
    assert robot.credits == [
        (first.feedback_credited_step, 10.0),
        (second.feedback_credited_step + offset, 10.0),
    ]
    # the arbiter's count of the second run's episode 0 is its own, not the first run's
    assert [e.interventions for e in robot.ended] == [0, 1, 0, 1, 0]
    assert [e.final for e in robot.ended] == [True, True, False, True, False]  # never settled
    counts = count_episodes(robot, load_map("1"), LearnerConfig())
    assert (counts.ended, counts.interventions, counts.provisional) == (5, 2, 2)

    with pytest.raises(RunError, match="episode 0 in runs 1 and 2"):
        robot.find("0")
    assert robot.find("2:0").run == 1 and robot.find("1:2").position == 2
    with pytest.raises(RunError, match=r"no episode 3:0 \(it has 1:0-1:2, 2:0-2:1\)"):
        robot.find("3:0")
    assert [robot.label(e) for e in pick_episodes(robot, ["2:1", "1:0"])] == ["2:1", "1:0"]

    paths = write_report(run, episodes=["1:1", "2:1"])
    text = paths[-1].read_text()
    assert "The simulator started 2 times in this log" in text
    assert "recorded in all: 5 episodes ended, 2 interventions" in text
    for png in paths[:-1]:
        assert png.stat().st_size > 10_000, png


def test_an_unbroken_log_keeps_the_simulators_numbers(tmp_path):
    records = write_script(tmp_path / "events.msgpack", "s1", scripted_session("s1", episodes=3))
    robot = summarize(records, "s1").robots["r1"]
    assert robot.runs == 1 and [robot.label(e) for e in robot.episodes] == ["0", "1", "2"]
    assert robot.steps == sorted(robot.steps) and robot.steps[0] == 0


def event(number: int, kind: str, steps: int = 0) -> EpisodeEvent:
    return EpisodeEvent(
        robot="r1",
        episode=number,
        step=1000 * number + steps,
        kind=kind,
        episode_steps=steps,
        sim_time=0.0,
        wall_time=0.0,
        env_return=-float(steps),
    )


def started(robot: RobotSummary, number: int) -> None:
    robot.on_episode(event(number, "start"))


def ended(robot: RobotSummary, number: int, steps: int, kind: str = "goal") -> None:
    started(robot, number)
    robot.on_episode(event(number, kind, steps))


def teaching(robot: RobotSummary, number: int, interventions: int, final: bool = True) -> None:
    robot.on_teaching(
        TeachingStats(
            robot="r1", episode=number, final=final, interventions=interventions, teachers=()
        )
    )


def test_convergence_is_judged_by_the_map_run_and_counts_to_it_and_in_all():
    robot = RobotSummary("r1")
    for n, (steps, heard) in enumerate([(900, 6), (280, 2), (285, 1), (290, 1), (280, 0)]):
        ended(robot, n, steps)  # the last four reach the goal in about 28 s
        teaching(robot, n, heard)
    started(robot, 5)  # and one more, unfinished
    teaching(robot, 5, 3, final=False)

    # task 1's shortest time is 10.3 s: 28 s episodes are 2.7 times that, not learnt
    on_task_1 = count_episodes(robot, load_map("1"), LearnerConfig())
    assert not on_task_1.convergence.converged
    assert on_task_1.describe().startswith("The robot did not converge within the 5 episodes")

    # the long room's is 19 s: the same episodes have learnt it
    counts = count_episodes(robot, load_map(LONG_ROOM), LearnerConfig())
    assert counts.convergence.converged and counts.converged_at == "3"
    assert (counts.convergence.n_episodes, counts.convergence.interventions) == (4, 10)
    assert (counts.ended, counts.interventions) == (5, 10)
    assert (counts.unfinished, counts.unfinished_interventions) == (1, 3)
    assert counts.describe() == (
        "The robot converged after 4 episodes (2.9 robot minutes, at episode 3). To "
        "convergence: 4 episodes, 10 interventions; recorded in all: 5 episodes ended, 10 "
        "interventions, and 1 unfinished episode (3 interventions so far)."
    )
    one = replace(counts, interventions=1, unfinished_interventions=1, provisional=1)
    assert (
        "10 interventions; recorded in all: 5 episodes ended, 1 intervention, and 1 "
        in (one.describe())
        and "(1 intervention so far). 1 of the ended episodes lacks" in one.describe()
    )


def test_a_later_non_final_count_does_not_undo_a_final_one():
    robot = RobotSummary("r1")
    ended(robot, 0, 100)
    teaching(robot, 0, 4, final=True)
    teaching(robot, 0, 2, final=False)
    assert (robot.ended[0].interventions, robot.ended[0].final) == (4, True)


def test_the_summary_states_the_counts_and_what_they_mean(tmp_path):
    run = RunDir(tmp_path / "runs" / "s1")
    write_session_info(run, describe_session("s1", str(LONG_ROOM), {}))
    write_script(run.events, "s1", scripted_session("s1", episodes=3, steps=20))
    loaded = load_run(run)
    counts = loaded.counts()["r1"]
    text = write_report(run, loaded=loaded)[-1].read_text()
    assert counts.describe() in text
    assert "each within 2.5x the map's shortest time (19.0 s)" in text  # the map run
    assert "interventions are the utterances the arbiter understood" in text


def test_a_run_is_judged_with_the_settings_its_learner_recorded(tmp_path):
    """Half the speeds: the long room's shortest time doubles, and the summary says so."""
    run = RunDir(tmp_path / "runs" / "s1")
    write_session_info(run, describe_session("s1", str(LONG_ROOM), {}))
    write_script(run.events, "s1", scripted_session("s1", episodes=3, steps=20))
    slow = {a: (v / 2, w) for a, (v, w) in LearnerConfig().velocities.items()}
    learner = with_settings([f"velocities={json.dumps(slow)}", "converge_slack=3"])
    write_settings(run.path, "learner", learner)
    loaded = load_run(run)
    assert loaded.learner == learner
    text = write_report(run, loaded=loaded)[-1].read_text()
    assert "each within 3x the map's shortest time (38.0 s)" in text


def test_robust_limits_keep_a_first_episodes_huge_return_from_squashing_the_rest():
    returns = [-4092.0, -29028.0, -122.0, -10.0, -15.0, -16.0, -20.0, -12.0, -9.0]
    low, high = robust_limits(returns)
    assert -4092 < low < -122 and high > -9  # episode 2 shown, episodes 0 and 1 beyond
    assert robust_limits([-100.0, -80.0, -60.0, -50.0, -45.0]) is None  # nothing far out
    assert robust_limits([-5000.0, -10.0]) is None  # too few to tell

"""The experiments: one in-process run with the teacher through the arbiter's core, and a tiny
`voxshape experiment paper` end to end."""

from __future__ import annotations

import json

import pytest

from benchmarks.experiment import steps_per_second
from voxshape.cli import main
from voxshape.lab.experiment import distributed
from voxshape.lab.experiment.inprocess import SETTINGS, RunResult, RunSpec, run
from voxshape.lab.experiment.intervals import mean_ci, speedup_interval
from voxshape.lab.experiment.legend import SETTING_STYLES
from voxshape.lab.experiment.paper_report import report
from voxshape.lab.experiment.published import PAPER_AVERAGE, paper_average
from voxshape.lab.experiment.summary import summarize
from voxshape.runtime.settings import SettingsError, replaced
from voxshape.services.sim.task import Simulation
from voxshape.services.simteacher.teacher import PERSON, TIRELESS, TeacherProfile
from voxshape.world.maps import TASKS


def test_mean_and_95_percent_interval():
    mean, half = mean_ci([1.0, 2.0, 3.0])
    assert mean == 2.0
    assert half == pytest.approx(4.303 * 1.0 / 3**0.5)
    assert mean_ci([5.0]) == (5.0, 0.0)


def test_feedback_goes_through_the_arbiter_into_the_learner():
    result = run(RunSpec("1", "rl+f", seed=0, max_episodes=2, profile=TIRELESS))
    c = result.counters
    assert result.episodes == 2 and not result.converged  # censored: too few episodes
    assert result.learning_time_s == pytest.approx(sum(result.durations_s), abs=0.1)
    assert c["arbiter.judgements"] > 20
    assert c["learner.feedback_credited"] >= c["arbiter.judgements"]  # one per credited step
    assert c.get("learner.feedback_dropped.too_old", 0) == 0
    assert c["arbiter.delay_candidates"] > 0  # it reacts to bumps and goals: delay learnt
    # 28% noise: slips, words not heard (said all the same), a few misheard
    assert result.interventions > c["arbiter.notices.understood"]
    assert c.get("arbiter.commands", 0) == c.get("learner.commands", 0)


def test_the_default_teacher_keeps_to_a_persons_budget():
    result = run(RunSpec("1", "rl+f", seed=0, max_episodes=4))
    minutes = result.learning_time_s / 60
    assert (
        0 < result.interventions <= PERSON.words_per_robot_minute * minutes + PERSON.words_at_once
    )
    assert result.spec["profile"]["words_per_robot_minute"] == 4.0  # the results say who taught


def test_runs_are_deterministic_and_plain_rl_has_no_teacher():
    spec = RunSpec("1", "rl", seed=3, max_episodes=2)
    first, again = run(spec), run(spec)
    assert first == again
    assert first.interventions == 0 and "arbiter.judgements" not in first.counters


def test_the_reference_path_gives_the_same_runs():
    # full numpy scans and a PyBullet query at every sub-step, against the fast path
    for spec in (RunSpec("3", "rl+t+f", 0, max_episodes=2), RunSpec("2", "rl+f", 1, 2)):
        assert run(spec).to_json() == run(spec, reference=True).to_json()


def test_the_experiment_benchmark_shares_the_time_among_the_cores():
    figures = steps_per_second([RunSpec("1", "rl+f", 0, max_episodes=1)], False)
    assert figures["steps"] > 0 and figures["steps_per_s"] > 0
    shares = figures["shares"]
    assert set(shares) == {"simulator", "learner", "arbiter", "teacher", "rest"}
    assert all(shares[core] > 0 for core in ("simulator", "learner", "arbiter", "teacher"))
    assert sum(shares.values()) == pytest.approx(1, abs=0.01)
    assert Simulation.step.__name__ == "step"  # the timing wrappers are gone


def test_experiments_run_on_a_users_own_map_file(tmp_path, capsys):
    room = tmp_path / "my-room.toml"
    room.write_text(TASKS["1"].read_text().replace("Task 1: open room", "my room"))
    out = tmp_path / "paper"
    code = main(
        ["experiment", "paper", "--tasks", f"2,{room}", "--settings", "rl+f", "--seeds", "1",
         "--max-episodes", "2", "--out", str(out), "--no-progress"]
    )  # fmt: skip
    assert code == 0
    results = json.loads((out / "results.json").read_text())
    assert set(results["tasks"]) == {"2", str(room)}
    assert "| my-room.toml |" in (out / "report.md").read_text()  # named by its file
    broken = tmp_path / "broken.toml"
    broken.write_text("size = [6.0]\n")
    with pytest.raises(SystemExit):
        main(["experiment", "sweep", "--tasks", f"1,{broken}", "--rate", "4"])
    assert "broken.toml" in capsys.readouterr().err  # the loader's reason, naming the file


def test_experiment_paper_end_to_end(tmp_path, capsys):
    out = tmp_path / "paper"
    code = main(
        ["experiment", "paper", "--tasks", "1", "--settings", "rl,rl+t+f", "--seeds", "2",
         "--max-episodes", "2", "--out", str(out), "--no-progress"]
    )  # fmt: skip
    assert code == 0
    results = json.loads((out / "results.json").read_text())
    assert results["seeds"] == 2
    for setting in ("rl", "rl+t+f"):
        cell = results["tasks"]["1"][setting]
        assert cell["runs"] == 2 and cell["episodes"] == 2.0
        assert cell["converged_fraction"] == 0.0  # censored at 2 episodes
        assert cell["learning_time_s"] > 0 and "learning_time_s_ci95" in cell
    assert results["tasks"]["1"]["rl"]["interventions"] == 0
    assert results["tasks"]["1"]["rl+t+f"]["interventions"] > 0
    # both censored: neither mean is the truth, so the ratio is no bound either way
    assert set(results["speedup"]) == {"rl+t+f"} and results["speedup_bound"]["rl+t+f"] == "none"
    low, high = results["speedup_ci95"]["rl+t+f"]
    assert low <= results["speedup"]["rl+t+f"] * 1.0001 and high >= low
    assert set(results["interventions"]) == {"rl+t+f"}
    streamed = [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()]
    assert sorted(map(json.dumps, streamed)) == sorted(map(json.dumps, results["runs"]))
    assert len(results["runs"]) == 4 and all(r["trace_steps"] > 0 for r in results["runs"]
                                             if r["setting"] == "rl+t+f")  # fmt: skip
    dictated = [r["dictation_words"] for r in results["runs"] if r["setting"] == "rl+t+f"]
    assert all(0 < words < r for words, r in zip(dictated, [r["trace_steps"] for r in
               results["runs"] if r["setting"] == "rl+t+f"], strict=True))  # fmt: skip
    assert results["dictation_words"]["rl+t+f"] == sum(dictated) / 2
    assert all(r["dictation_s"] > 0 for r in results["runs"] if r["setting"] == "rl+t+f")
    report = (out / "report.md").read_text()
    assert "Table 2" in report and "Table 3" in report and "103.93" in report
    learning = results["interventions"]["rl+t+f"]
    said = sum(dictated) / 2
    assert f"| RL + T + F | {said:.1f} | {learning:.1f} | {said + learning:.1f} |" in report
    assert "≥" in report and "censored" in report
    assert (out / "figure2.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "report.md" in capsys.readouterr().out


def test_unknown_setting_is_refused(capsys):
    with pytest.raises(SystemExit):
        main(["experiment", "paper", "--settings", "rl,magic"])
    assert "unknown setting magic" in capsys.readouterr().err


def one_run_of_task_1(out, setting: str, episodes: int) -> list[str]:
    """The arguments of `voxshape experiment paper` for one seed of task 1 in `setting`."""
    return ["experiment", "paper", "--tasks", "1", "--settings", setting, "--seeds", "1",
            "--max-episodes", str(episodes), "--out", str(out), "--no-progress"]  # fmt: skip


def test_learner_settings_reach_every_run_and_a_bad_one_is_refused_first(tmp_path, capsys):
    out = tmp_path / "paper"
    argv = one_run_of_task_1(out, "rl", episodes=1)
    assert main([*argv, "--set", "goal_sectors=nine"]) == 2
    assert "goal_sectors takes an int" in capsys.readouterr().err and not out.exists()
    assert main([*argv, "--set", "goal_sectors=8", "--set", "converge_margin=0.3"]) == 0
    results = json.loads((out / "results.json").read_text())
    assert results["learner_settings"] == ["goal_sectors=8", "converge_margin=0.3"]
    recorded = json.loads((out / "settings.json").read_text())  # the effective settings
    assert recorded["learner"]["goal_sectors"] == 8 and recorded["learner"]["alpha"] == 0.2
    assert "the slowest within 30% of the fastest" in (out / "report.md").read_text()
    assert recorded["teacher"]["words_per_robot_minute"] == 4.0  # the person's


def test_first_seed_runs_other_seeds_and_says_which(tmp_path):
    out = tmp_path / "paper"
    assert (
        main([*one_run_of_task_1(out, "rl", episodes=1), "--seeds", "2", "--first-seed", "10"]) == 0
    )
    results = json.loads((out / "results.json").read_text())
    assert sorted(r["seed"] for r in results["runs"]) == [10, 11]
    assert results["seeds"] == 2 and results["first_seed"] == 10
    assert "seeds 10-11" in (out / "report.md").read_text()
    assert main([*one_run_of_task_1(out, "rl", episodes=1), "--first-seed", "-1"]) == 2


def test_pooled_experiments_are_the_experiment_of_all_their_seeds(tmp_path, capsys):
    def paper(out, *extra):
        argv = [*one_run_of_task_1(tmp_path / out, "rl,rl+f", episodes=2), *extra]
        assert main(argv) == 0

    paper("both", "--seeds", "2")
    paper("first")
    paper("second", "--first-seed", "1")
    assert main(["experiment", "pool", str(tmp_path / "first"), str(tmp_path / "second"),
                 "--out", str(tmp_path / "pooled")]) == 0  # fmt: skip
    pooled, both = (json.loads((tmp_path / d / "results.json").read_text())
                    for d in ("pooled", "both"))  # fmt: skip
    for key in ("seeds", "tasks", "speedup", "speedup_ci95", "interventions"):
        assert pooled[key] == both[key]
    assert pooled["pooled"] == [str(tmp_path / "first"), str(tmp_path / "second")]
    assert "seeds 0-1" in (tmp_path / "pooled" / "report.md").read_text()
    assert (tmp_path / "pooled" / "settings.json").read_text() == (
        tmp_path / "both" / "settings.json"
    ).read_text()
    capsys.readouterr()

    def refused(*dirs: str) -> str:
        argv = ["experiment", "pool", *(str(tmp_path / d) for d in dirs)]
        assert main([*argv, "--out", str(tmp_path / "refused")]) == 2
        assert not (tmp_path / "refused").exists()
        return capsys.readouterr().err

    assert "seed 0 is in more than one of" in refused("first", "both")
    paper("other", "--first-seed", "1", "--set", "alpha=0.1")
    assert "learner_settings ['alpha=0.1'] differ" in refused("first", "other")
    assert "not the results.json" in refused("first", "nowhere")


def test_teacher_settings_reach_every_run_and_a_bad_one_is_refused_first(tmp_path, capsys):
    out = tmp_path / "paper"
    argv = one_run_of_task_1(out, "rl+f", episodes=2)
    assert main([*argv, "--teacher", "repeat_after=-1"]) == 2
    assert "repeat_after >= 0" in capsys.readouterr().err and not out.exists()
    assert main([*argv, "--teacher", "shedule=3"]) == 2
    assert "KEY is one of" in capsys.readouterr().err and not out.exists()
    tireless = [*argv, "--teacher-profile", "tireless"]
    assert main([*tireless, "--teacher", "repeat_after=3"]) == 0
    results = json.loads((out / "results.json").read_text())
    assert results["teacher_settings"] == ["repeat_after=3"]
    assert results["teacher_profile"] == "tireless"
    assert (
        "The simulated teacher: tireless (no budget, judging every 1 s), with repeat_after=3."
        in (out / "report.md").read_text()
    )
    patient = results["runs"][0]
    chatty = run(RunSpec("1", "rl+f", 0, max_episodes=2, profile=TIRELESS))
    per_second = [r["interventions"] / sum(r["durations_s"]) for r in (patient, chatty.to_json())]
    assert 0 < per_second[0] < per_second[1]  # no praise a second on a steady way


def test_the_teacher_schedule_is_set_field_by_field():
    silent = ("schedule.permanent=0", "schedule.sporadic=0")
    result = run(RunSpec("1", "rl+f", 0, max_episodes=2, teacher=silent))
    assert result.interventions == 0 and result.spec["teacher"] == silent
    with pytest.raises(SettingsError, match=r"'schedule=0.5': .* schedule\.FIELD=VALUE"):
        replaced(TeacherProfile(), ["schedule=0.5"], "--teacher")
    with pytest.raises(SettingsError, match=r"'schedule\.often=1': no setting 'often'; KEY is one"):
        replaced(TeacherProfile(), ["schedule.often=1"], "--teacher")


def test_experiment_sweep_end_to_end(tmp_path, capsys):
    out = tmp_path / "sweep"
    code = main(
        ["experiment", "sweep", "--tasks", "1", "--seeds", "1", "--max-episodes", "2",
         "--noise", "0,0.5", "--delay", "1.5", "--out", str(out), "--no-progress",
         "--teacher-profile", "judging", "--set", "potential=none", "--set", "lookahead_weight=0"]
    )  # fmt: skip
    assert code == 0
    points = json.loads((out / "sweep.json").read_text())["points"]
    assert [(p["axis"], p["value"], p["correction"]) for p in points] == [
        ("rl", 0.0, True),
        ("noise", 0.0, True),
        ("noise", 0.5, True),
        ("delay", 1.5, True),
        ("delay", 1.5, False),
    ]
    assert points[0]["speedup"] == 1.0
    assert all(p["speedup"] > 0 and p["runs"] == 1 for p in points)
    assert all(p["speedup_ci95"][0] <= p["speedup"] * 1.0001 for p in points)
    # The arbiter learns the 1.5 s delay from a judging teacher's reactions to bumps and
    # goals within two episodes (a robot without the potential or the lookahead, which bumps
    # more);
    # without the correction it keeps TAMER's fixed window.
    assert points[-2]["delay_learned_fraction"] == 1.0
    assert points[-1]["delay_learned_fraction"] == 0.0
    assert "speedup over RL" in (out / "sweep.md").read_text()
    assert (out / "sweep.png").read_bytes()[:4] == b"\x89PNG"
    runs = [json.loads(line)["spec"] for line in (out / "runs.jsonl").read_text().splitlines()]
    ran = {(r["setting"], r["noise"], r["delay"], r["delay_learning"]) for r in runs}
    assert ran == {("rl", None, None, True), ("rl+f", 0.0, None, True), ("rl+f", 0.5, None, True),
                   ("rl+f", None, 1.5, True), ("rl+f", None, 1.5, False)}  # fmt: skip


def test_the_budget_sweep_runs_both_feedback_settings_at_each_rate(tmp_path):
    out = tmp_path / "budget"
    code = main(
        ["experiment", "sweep", "--tasks", "1", "--seeds", "1", "--max-episodes", "2",
         "--rate", "0,4", "--out", str(out), "--no-progress"]
    )  # fmt: skip
    assert code == 0
    points = json.loads((out / "sweep.json").read_text())["points"]
    assert [(p["axis"], p["value"], p["setting"]) for p in points] == [
        ("rl", 0.0, "rl"),
        ("rate", 0.0, "rl+f"),
        ("rate", 4.0, "rl+f"),
        ("rate", 0.0, "rl+t+f"),
        ("rate", 4.0, "rl+t+f"),
    ]
    assert all(p["words_per_minute"] >= 0 for p in points)
    budgeted = [p for p in points if p["value"] == 4.0]
    assert all(
        p["words_per_minute"] <= 4.0 + 2 / (p["mean_learning_time_s"] / 60) for p in budgeted
    )
    runs = [json.loads(line)["spec"] for line in (out / "runs.jsonl").read_text().splitlines()]
    profiles = {
        (r["profile"]["words_per_robot_minute"], r["profile"]["salient"])
        for r in runs
        if r["setting"] != "rl"
    }
    assert profiles == {(0.0, False), (4.0, True)}  # the tireless teacher, and a person
    assert (out / "sweep.png").read_bytes()[:4] == b"\x89PNG"


def test_sweep_needs_something_to_sweep(capsys):
    assert main(["experiment", "sweep", "--tasks", "1", "--seeds", "1"]) == 2
    assert "give --noise" in capsys.readouterr().err


def test_the_distributed_run_learns_exactly_what_the_in_process_run_learns():
    """Every service its own process over zenoh, on the lockstep clock: same seed, same
    episodes, step for step; the bus's learner given the same settings (and judged by them)."""
    spec = RunSpec("1", "rl", seed=0, max_episodes=2, learner=("alpha=0.5", "min_hold=2"))
    local, bus = distributed.in_process(spec), distributed.over_zenoh(spec, timeout_s=300)
    assert bus.durations_s == local.durations_s and len(bus.durations_s) == 2


@pytest.mark.long
def test_over_zenoh_the_simulated_teacher_says_as_much_per_robot_minute_as_in_process():
    """Lockstep runs ~50x real time: the teacher, the speech service and the arbiter keep to
    robot time (rate, delays), so the teacher is heard as often as in-process, not refused
    as a flood (before: 4% of its words). Pooled over three seeds: how much a person says
    depends on what the robot does, which differs between the two (one seed alone: 0.58-1.18)."""
    specs = [RunSpec("4", "rl+f", seed, max_episodes=3) for seed in range(3)]  # robot minutes
    runs = [(distributed.in_process(s), distributed.over_zenoh(s, timeout_s=300)) for s in specs]
    per_minute = [
        sum(r.interventions for r in side) / (sum(sum(r.durations_s) for r in side) / 60)
        for side in zip(*runs, strict=True)
    ]
    assert 0.67 < per_minute[1] / per_minute[0] < 1.5, per_minute


def test_the_speedup_interval_holds_the_speedup_and_narrows_with_agreeing_seeds():
    def runs(times: list[float]) -> list[RunResult]:
        return [RunResult("1", "rl", i, True, 1, t, 0, 0, [t], False, (0, 0), {})
                for i, t in enumerate(times)]  # fmt: skip

    rl = runs([100.0, 140.0, 60.0, 100.0])
    low, high = speedup_interval(rl, runs([10.0, 12.0, 8.0, 10.0]), ["1"])
    assert low < 10.0 < high
    low2, high2 = speedup_interval(rl, runs([2.0, 30.0, 1.0, 7.0]), ["1"])
    assert high2 - low2 > 2 * (high - low)  # seeds that disagree: a wider interval


def result(task: str, setting: str, seed: int, minutes: float, interventions: int = 0):
    return RunResult(task, setting, seed, True, 5, minutes * 60, interventions, 0, [60.0] * 5,
                     True, (0.2, 0.8), {})  # fmt: skip


def test_the_papers_averages_are_over_the_tasks_run():
    assert paper_average(["1", "2", "3", "4"]) == PAPER_AVERAGE  # as printed
    one = paper_average(["1"])
    assert one["minutes"] == {"rl": 103.93, "rl+f": 19.59, "rl+t+f": 12.85}
    assert one["speedup"]["rl+t+f"] == pytest.approx(103.93 / 12.85)
    assert one["interventions"] == {"rl+f": 71, "rl+t+f": 23}
    two = paper_average(["2", "1", "my-room.toml"])  # a map file has no paper figure
    assert two["minutes"]["rl"] == pytest.approx((103.93 + 66.4) / 2)
    assert two["speedup"]["rl+f"] == pytest.approx((103.93 + 66.4) / (19.59 + 15.1))
    assert "rl+t+f-perfect" not in two["minutes"]  # the paper ran it on task 2 only
    assert paper_average(["2"])["speedup"]["rl+t+f-perfect"] == pytest.approx(66.4 / 7.6)
    assert paper_average(["my-room.toml"])["speedup"] == {}


def test_a_report_on_some_tasks_compares_with_the_paper_on_those_tasks_only():
    runs = [result("1", "rl", s, 20.0) for s in range(2)]
    runs += [result("1", "rl+t+f", s, 5.0, 30) for s in range(2)]
    summary = summarize(runs, 2)
    assert summary["paper"]["tasks"] == ["1"]
    text = report(summary, "voxshape experiment paper --tasks 1", 1.0)
    assert "| Avg of T1 | 20.0 | 103.93 | 5.0 | 12.85 |" in text  # not the four-task 92.54
    assert f"| RL + T + F | 4.00 | 4.00-4.00 | {103.93 / 12.85:.2f} |" in text  # not 5.4
    assert "| Avg of T1 | 30.0 | 23 |" in text  # interventions: task 1's, not 42
    assert "92.54" not in text and "5.4 |" not in text
    assert "over the same built-in tasks (T1)" in text

    # With a map file: the average of all tasks has no paper figure, the built-in one has.
    runs += [result("/x/my-room.toml", "rl", s, 40.0) for s in range(2)]
    runs += [result("/x/my-room.toml", "rl+t+f", s, 10.0, 50) for s in range(2)]
    text = report(summarize(runs, 2), "voxshape experiment paper --tasks 1,my-room.toml", 1.0)
    assert "| Avg of my-room.toml, T1 | 30.0 | - | 7.5 | - |" in text
    assert "| Avg of T1 | 20.0 | 103.93 | 5.0 | 12.85 |" in text
    assert "| RL + T + F | 4.00 | 4.00-4.00 | - |" in text
    assert f"| RL + T + F | 4.00 | {103.93 / 12.85:.2f} |" in text  # the built-in tasks alone
    assert "Map files (my-room.toml) have no paper figure" in text

    four = [result(t, st, s, m) for t in "1234" for st, m in (("rl", 20.0), ("rl+f", 10.0))
            for s in range(2)]  # fmt: skip
    text = report(summarize(four, 2), "voxshape experiment paper", 1.0)
    assert "| Avg | 20.0 | 92.54 | 10.0 | 24.08 |" in text  # the printed four-task figures
    assert "| RL + F | 2.00 | 2.00-2.00 | 3.84 |" in text


def test_every_setting_has_its_name_and_marker_in_the_legend():
    """The reports name and draw a setting from legend.py: a setting added to SETTINGS without
    its line there would fail every report that ran it."""
    assert list(SETTING_STYLES) == list(SETTINGS)  # the tables' order is the settings'
    assert len({s.label for s in SETTING_STYLES.values()}) == len(SETTINGS)
    assert len({s.marker for s in SETTING_STYLES.values()}) == len(SETTINGS)


def test_a_report_of_too_few_seeds_says_its_intervals_mean_little():
    """With 2 seeds a cell read "5.5 ± 31.8" and nothing said that two seeds cannot decide."""

    def runs(seeds: int) -> list[RunResult]:
        pairs = (("rl", 20.0), ("rl+f", 10.0))
        return [result("1", st, s, m + s) for st, m in pairs for s in range(seeds)]

    text = report(summarize(runs(2), 2), "voxshape experiment paper --seeds 2", 1.0)
    assert "**Too few seeds to say much**: 2 seed(s)" in text and "--seeds 5 or more" in text
    assert "Too few seeds" not in report(summarize(runs(5), 5), "voxshape experiment paper", 1.0)

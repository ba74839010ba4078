"""Every command and code block of the README is run by a test: the quick ones here, as
written (in a scratch directory, on loopback); the long ones (a session, the paper's
experiment) by the test COVERED names, which runs the same command on a smaller job. A
command added to the README without an entry in COVERED fails the suite."""

from __future__ import annotations

import importlib
import os
import re
import shlex
import shutil
import subprocess
import sys
import tomllib
import warnings
from pathlib import Path

import gymnasium as gym
import pytest

from tests.conftest import ROOT, VOXSHAPE
from tests.logger_support import scripted_session, write_script
from voxshape.services.logger.run import RunDir, describe_session, write_session_info
from voxshape.services.sim import gym_env

README = ROOT / "README.md"
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)
INLINE = re.compile(r"`([^`]+)`")
# What counts as a command, in a fenced `sh` block or in an inline code span.
COMMAND = re.compile(r"(voxshape|make|docker compose|\.ci/run)(\s|$)")

HERE = "tests.test_readme"
DEMO = "tests.test_demo::test_the_demo_trains_task_1_to_convergence_and_says_where_its_results_are"
TYPED = "tests.test_teach::test_typed_words_reach_the_utterance_topic"
# README command (whitespace collapsed) -> the tests that run it (module::function).
COVERED: dict[str, tuple[str, ...]] = {
    # Minutes each: the make targets are checked to run the commands below, which are tested.
    "make demo": (f"{HERE}::test_the_make_targets_run_what_the_readme_says", DEMO),
    "make test": (f"{HERE}::test_the_make_targets_run_what_the_readme_says",),
    "make lint": (f"{HERE}::test_the_make_targets_run_what_the_readme_says",),
    ".ci/run": (f"{HERE}::test_ci_runs_make_test",),
    # A whole session: with mock speech at 20x; the audio path on its own.
    "voxshape demo": (
        DEMO,
        "tests.test_simteacher_service::test_its_synthesized_audio_is_recognized_by_pocketsphinx",
    ),
    "voxshape up": (
        "tests.test_launcher::test_up_starts_the_compose_services_and_stops_cleanly",
        "tests.test_first_hour::test_the_first_hour_of_a_new_user",
    ),
    "voxshape status --connect ...": (
        "tests.test_session_end::test_sigterm_ends_the_session_and_status_names_it_before",
    ),
    "voxshape up --robots r1,r2 --rtf 5": (
        "tests.test_launcher::test_a_second_up_starts_a_new_run_with_fresh_learners_and_resume_resumes",
    ),
    "voxshape web": (
        "tests.test_web::test_a_browser_teaches_through_the_page",
        "tests.test_web::test_voxshape_web_stops_cleanly_on_sigterm",
    ),
    "voxshape demo --web": (
        "tests.test_web::test_the_demo_with_web_serves_the_page_and_runs_no_simulated_teacher",
        "tests.test_web::test_a_browser_teaches_through_the_page",
    ),
    "voxshape demo --resume": (
        "tests.test_new_user_paths::test_demo_resume_goes_on_with_the_latest_demo",
    ),
    "voxshape demo --task my-map.toml": (
        "tests.test_first_hour::test_the_demo_on_a_map_file_converges_and_says_so",
    ),
    # Interactive: typed words through a test router; no microphone here.
    "voxshape teach": (TYPED,),
    "voxshape teach --teacher ana --robot r1": (
        TYPED,
        "tests.test_first_hour::test_the_first_hour_of_a_new_user",
    ),
    "voxshape teach --mic": ("tests.test_teach::test_no_microphone_is_a_clear_error",),
    "voxshape teach --connect tls/lab.example:7448 --tls-root-ca ca.pem --user ana --teacher ana": (
        "tests.test_multihost::test_a_typed_good_crosses_three_hosts_to_the_learner",
        "tests.test_security::test_tls_with_a_certificate_works_and_plain_tcp_cannot_use_the_tls_endpoint",
    ),
    "docker compose up": (
        "tests.test_compose::test_docker_compose_accepts_the_file",
        "tests.test_compose::test_every_service_joins_a_secured_router_and_announces_itself",
    ),
    "voxshape status": (
        f"{HERE}::test_status_as_written",
        "tests.test_first_hour::test_the_first_hour_of_a_new_user",
    ),
    # A live viewer needs a recording: the test serves a scripted one on free ports.
    "voxshape view": (
        "tests.test_logger::test_view_serves_the_web_viewer_on_localhost_and_prints_its_url",
    ),
    "voxshape report runs/default": (f"{HERE}::test_report_as_written",),
    "voxshape train --task 2 --seed 1": (f"{HERE}::test_train_as_written",),
    # Hours of runs: one task, a few short runs (workers default to the cores, 2 here).
    "voxshape experiment paper --seeds 10 --workers 2": (
        "tests.test_experiment::test_experiment_paper_end_to_end",
    ),
    "voxshape experiment paper --seeds 10 --first-seed 30 --workers 2 --settings rl,rl+f,"
    "rl+f-perfect,rl+t,rl+t+f,rl+t+f-perfect --out docs/results/paper-seeds30": (
        "tests.test_experiment::test_first_seed_runs_other_seeds_and_says_which",
        "tests.test_experiment::test_experiment_paper_end_to_end",
    ),
    "voxshape experiment paper --tasks docs/results/other-maps/office.toml,"
    "docs/results/other-maps/corridor.toml,docs/results/choice-maps/cluttered.toml,"
    "docs/results/new-maps/uturn.toml,docs/results/choice-maps/pocket.toml,"
    "docs/results/new-maps/zigzag.toml --settings rl,rl+f,rl+f-perfect,rl+t+f --seeds 10"
    " --first-seed 30 --workers 2 --out docs/results/maps-seeds30": (
        "tests.test_experiment::test_experiments_run_on_a_users_own_map_file",
        "tests.test_experiment::test_first_seed_runs_other_seeds_and_says_which",
    ),
    "voxshape experiment paper --set potential=none --settings rl,rl+f,rl+f-perfect,rl+t+f"
    " --seeds 10 --first-seed 30 --workers 2 --out docs/results/paper-regime-seeds30": (
        "tests.test_experiment::test_first_seed_runs_other_seeds_and_says_which",
        "tests.test_experiment::test_learner_settings_reach_every_run_and_a_bad_one_is_refused_first",
    ),
    # A service that runs until stopped: a tiny map file's episodes on a test router.
    "voxshape sim --task my-map.toml": (
        "tests.test_sim_service::test_episode_events_and_outcome_on_the_terminal_observation",
    ),
    "voxshape map my-map.toml --png map.png": (f"{HERE}::test_map_as_written",),
}


def fences(page: Path = README) -> list[tuple[str, str]]:
    """A page's fenced blocks: (language, body)."""
    return FENCE.findall(page.read_text())


def readme_commands(page: Path = README) -> list[str]:
    """Commands of the `sh` blocks (comments dropped) and inline ones, whitespace collapsed."""
    found = []
    for language, body in fences(page):
        if language == "sh":
            found += [line.split("#", 1)[0].strip() for line in body.splitlines()]
    prose = FENCE.sub("", page.read_text())
    found += [" ".join(span.split()) for span in INLINE.findall(prose)]
    return list(dict.fromkeys(c for c in found if COMMAND.match(c)))


def docs_commands() -> list[tuple[str, str]]:
    """(page, command) of every `voxshape` command of docs/*.md, as readme_commands reads."""
    return [
        (page.name, command)
        for page in sorted((ROOT / "docs").glob("*.md"))
        for command in readme_commands(page)
        if command.startswith("voxshape ")
    ]


def run(argv: list[str], cwd, timeout: float = 60, **env: str) -> subprocess.CompletedProcess:
    """A command in a fresh process, with no VOXSHAPE_* of the caller (the defaults)."""
    clean = {k: v for k, v in os.environ.items() if not k.startswith("VOXSHAPE_")}
    return subprocess.run(
        argv, capture_output=True, text=True, timeout=timeout, cwd=cwd, env={**clean, **env}
    )


def as_written(command: str) -> list[str]:
    """`voxshape ...` of the README, run with this environment's voxshape."""
    argv = shlex.split(command)
    assert argv[0] == "voxshape" and command in readme_commands(), command
    return [VOXSHAPE, *argv[1:]]


def test_every_readme_command_has_a_test():
    found = readme_commands()
    missing = [c for c in found if c not in COVERED]
    assert not missing, f"README commands with no test: add them to COVERED: {missing}"
    stale = [c for c in COVERED if c not in found]
    assert not stale, f"COVERED names commands the README no longer has: {stale}"


def test_every_test_in_the_table_exists():
    for command, tests in COVERED.items():
        assert tests, command
        for test in tests:
            module, _, name = test.partition("::")
            function = getattr(importlib.import_module(module), name, None)
            assert name.startswith("test_") and callable(function), f"{command}: no {test}"


def test_fenced_blocks_are_commands_or_pictures():
    """A new kind of block (python, toml...) fails here until a test runs it."""
    for language, body in fences():
        assert language in ("sh", ""), f"a ```{language} block: run it in {__name__}"
        if language == "":  # a diagram, with arrows; commands go in ```sh blocks
            assert re.search(r"-->|<--", body), f"label this block ```sh:\n{body}"


@pytest.mark.parametrize("command", [c for c in readme_commands() if c.startswith("voxshape")])
def test_every_voxshape_command_parses(command):
    """Flags of the heavy commands too: a renamed flag fails here, in milliseconds."""
    from voxshape.cli import parser

    try:
        parser().parse_args(shlex.split(command)[1:])
    except SystemExit as e:
        pytest.fail(f"{command!r} does not parse (exit {e.code})")


# A command's shape rather than a command: `--seeds N`, `paper|sweep`, `[--json]`, `...`.
PLACEHOLDER = re.compile(r"^([A-Z][A-Z_]*(=[A-Z_]+)?|.*\|.*|[<\[].*|.*\.\.\..*)$")


def is_shape(command: str) -> bool:
    return any(PLACEHOLDER.match(a) for a in shlex.split(command)[1:])


@pytest.mark.parametrize(
    ("page", "command"), [(p, c) for p, c in docs_commands() if not is_shape(c)]
)
def test_every_voxshape_command_of_the_docs_parses(page, command, tmp_path, monkeypatch):
    """docs/ promise as much as the README: each command's flags are the parser's (run
    from the root, with the user's own map the pages name, my-map.toml)."""
    from voxshape.cli import parser

    argv = shlex.split(command)[1:]
    shutil.copy(ROOT / "voxshape" / "world" / "maps" / "task1.toml", tmp_path / "my-map.toml")
    (tmp_path / "docs").symlink_to(ROOT / "docs")  # the maps the pages name, from the root
    monkeypatch.chdir(tmp_path)
    try:
        parser().parse_args(argv)
    except SystemExit as e:
        pytest.fail(f"{page}: {command!r} does not parse (exit {e.code})")


@pytest.mark.skipif(shutil.which("make") is None, reason="no make")
def test_the_make_targets_run_what_the_readme_says():
    """`make -n` prints each target's commands without running them (with the Makefile's
    defaults: not a TEST_WORKERS of the caller's, as `TEST_WORKERS=2 make test` exports)."""
    expected = {
        "demo": [".venv/bin/voxshape demo"],
        "test": [".venv/bin/ruff check .", ".venv/bin/pytest -n 4 --dist loadgroup"],
        "lint": [".venv/bin/ruff check .", ".venv/bin/ruff format --check ."],
    }
    for target, lines in expected.items():
        result = run(["env", "-u", "TEST_WORKERS", "make", "-n", target], ROOT, timeout=30)
        assert result.returncode == 0, result.stderr
        assert set(lines) <= set(result.stdout.splitlines()), (target, result.stdout)


@pytest.mark.skipif(shutil.which("make") is None, reason="no make")
def test_make_demo_installs_what_running_needs_and_make_test_the_rest():
    """`make -n -B` prints what a clean clone's target would install: the demo none of the
    tests' packages (pytest, Playwright, Ray, a vosk model, Moonshine base: pyproject's test,
    cluster and moonshine extras; chromium), the tests all of them."""
    installs = {}
    for target in ("demo", "test"):
        result = run(["make", "-n", "-B", target], ROOT, timeout=30)
        assert result.returncode == 0, result.stderr
        lines = result.stdout.splitlines()
        installs[target] = [line for line in lines if "install" in line or "PACKAGES=" in line]
    assert any("-e '.[whisper]'" in line for line in installs["demo"]), installs["demo"]
    demo = " ".join(installs["demo"])
    assert not any(w in demo for w in ("test", "cluster", "moonshine", "chromium"))
    assert any("-e '.[whisper,moonshine,test,cluster]'" in line for line in installs["test"])
    assert any("chromium" in line for line in installs["test"]), installs["test"]
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    running = " ".join(extras["dependencies"] + extras["optional-dependencies"]["whisper"])
    for tested in ("pytest", "playwright", "ray", "vosk-model", "rosbags", "hypothesis"):
        assert tested not in running


def test_ci_runs_make_test():
    script = ROOT / ".ci" / "run"
    assert os.access(script, os.X_OK)
    assert script.read_text().splitlines()[-1] == "exec make test"


def test_status_as_written(tmp_path, session_id):
    """No router on the default port: a clear error, not a traceback (a router there, from
    someone's session: our own session id is empty)."""
    env = {"VOXSHAPE_SESSION": session_id, "VOXSHAPE_CONNECT_TIMEOUT": "2"}
    result = run(as_written("voxshape status"), tmp_path, **env)
    assert "Traceback" not in result.stderr
    if result.returncode == 0:
        assert f"session '{session_id}': 0 node(s) present" in result.stdout
    else:
        assert result.returncode == 2 and "voxshape status: error:" in result.stderr


def test_report_as_written(tmp_path):
    run_dir = RunDir(tmp_path / "runs" / "default")
    write_session_info(run_dir, describe_session("default", "1", {"task": "1"}))
    write_script(run_dir.events, "default", scripted_session("default", episodes=3, steps=20))
    result = run(as_written("voxshape report runs/default"), tmp_path)
    assert result.returncode == 0, result.stderr
    report = tmp_path / "runs" / "default" / "report"
    assert "trajectories-r1.png" in (report / "summary.md").read_text()
    assert len(list(report.glob("*.png"))) >= 3


def test_train_as_written(tmp_path):
    result = run(as_written("voxshape train --task 2 --seed 1"), tmp_path, timeout=120)
    assert result.returncode == 0, result.stderr
    assert re.search(r"task 2, seed 1: converged after \d+ episodes", result.stdout), result.stdout


def test_map_as_written(tmp_path):
    shutil.copy(ROOT / "voxshape" / "world" / "maps" / "task3.toml", tmp_path / "my-map.toml")
    result = run(as_written("voxshape map my-map.toml --png map.png"), tmp_path)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "map.png").read_bytes()[:4] == b"\x89PNG"


def test_the_gymnasium_line_runs_in_a_fresh_interpreter(tmp_path):
    """The README's `gym.make(...)` as written, in `python -I`: nothing of ours imported
    before it, only the installed package on the path."""
    prose = FENCE.sub("", README.read_text())
    (snippet,) = [s for s in INLINE.findall(prose) if s.startswith("gym.make(")]
    assert f'"{gym_env.MAKE_ID}"' in snippet
    code = "\n".join(
        [
            "import gymnasium as gym",
            f"env = {snippet}",
            "env.reset(seed=0)",
            "env.step(env.action_space.sample())",
            "print(env.spec.id)",
            "env.close()",
        ]
    )
    result = run([sys.executable, "-I", "-c", code], tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == [gym_env.ENV_ID]


def test_registration_is_idempotent():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # gymnasium warns when an id is overridden
        gym_env.register()
        gym_env.register()
    assert gym.spec(gym_env.ENV_ID).entry_point is gym_env.NavigationEnv

"""Settings written once (voxshape/runtime/settings.py): a config dataclass's option fields
become flags with their help, variable and default; read back, a flag overrides its variable,
which overrides the default; `--set` takes only the fields without a flag of their own."""

from __future__ import annotations

import argparse
import json
import re
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest
import yaml

from tests.conftest import ROOT, VOXSHAPE
from voxshape.cli import COMMANDS, parser
from voxshape.runtime.settings import (
    SETTINGS_FILE,
    ConfigError,
    SettingsError,
    add_options,
    add_settings_argument,
    from_record,
    option,
    read_options,
    read_settings,
    record,
    replaced,
    write_settings,
)
from voxshape.services.learner.config import LearnerConfig, with_settings


@dataclass(frozen=True)
class Inner:
    level: int = 1


@dataclass(frozen=True)
class Example:
    rate: float = option(1.0, "things a second", env="EXAMPLE_RATE")
    mode: Literal["slow", "fast"] = option("slow", "how", env="EXAMPLE_MODE")
    names: tuple[str, ...] = option(
        ("a",), "a name", flag="--name", env="EXAMPLE_NAMES", repeat=True
    )
    where: Path | None = option(None, "a file", show="none: built in")
    loud: bool = option(False, "say more", env="EXAMPLE_LOUD")
    secret: str | None = option(None, "by its variable alone", env="EXAMPLE_SECRET", flag=None)
    tuned: float = 0.5  # no flag: --set tuned=0.7
    inner: Inner = field(default_factory=Inner)


def example(*argv: str, env: dict[str, str] | None = None) -> Example:
    command = argparse.ArgumentParser()
    add_options(command, Example)
    add_settings_argument(command, "Example", "tuned=0.7")
    args = command.parse_args(list(argv))
    return replaced(read_options(Example, args, env or {}), args.set)


def test_a_flag_overrides_its_variable_which_overrides_the_default():
    assert example() == Example()
    env = {"EXAMPLE_RATE": "2.5", "EXAMPLE_NAMES": "b, c", "EXAMPLE_LOUD": "yes"}
    assert example(env=env) == Example(rate=2.5, names=("b", "c"), loud=True)
    given = example("--rate", "4", "--name", "d", "--name", "e", "--loud", env=env)
    assert (given.rate, given.names, given.loud) == (4.0, ("d", "e"), True)
    assert example(env={"EXAMPLE_RATE": ""}).rate == 1.0  # an empty variable is unset
    assert example(env={"EXAMPLE_SECRET": "s3cret"}).secret == "s3cret"
    assert example("--where", "x.toml").where == Path("x.toml")
    assert example("--set", "tuned=0.7", "--set", "inner.level=3").tuned == 0.7


def test_the_help_says_the_variable_and_the_default_once_written():
    command = argparse.ArgumentParser()
    add_options(command, Example)
    text = " ".join(command.format_help().split())
    assert "--rate RATE things a second (EXAMPLE_RATE; default 1)" in text
    assert "--mode {slow,fast} how (EXAMPLE_MODE; default slow)" in text
    assert "--name NAME a name (repeatable; EXAMPLE_NAMES, comma-separated; default a)" in text
    assert "--where WHERE a file (default none: built in)" in text
    assert "--secret" not in text  # a variable alone


@pytest.mark.parametrize(
    ("argv", "env", "error"),
    [
        (["--rate", "fast"], {}, "--rate 'fast': not a valid float"),
        ([], {"EXAMPLE_RATE": "fast"}, "EXAMPLE_RATE='fast': not a valid float"),
        ([], {"EXAMPLE_MODE": "warp"}, "EXAMPLE_MODE='warp' is not one of slow, fast"),
        ([], {"EXAMPLE_LOUD": "maybe"}, "EXAMPLE_LOUD='maybe': say true or false"),
        (["--set", "rate=2"], {}, "'rate=2': rate has a flag of its own: --rate"),
        (["--set", "rat=2"], {}, "no setting 'rat'; did you mean rate? KEY is one of inner"),
        (["--set", "tuned=slow"], {}, "tuned takes a float"),
    ],
)
def test_a_bad_value_names_the_flag_or_variable_it_came_from(argv, env, error):
    with pytest.raises(ConfigError, match=re.escape(error)):
        example(*argv, env=env)


def test_one_setting_is_given_one_way():
    @dataclass(frozen=True)
    class Again:
        rate: float = option(2.0, "the same name")

    command = argparse.ArgumentParser()
    add_options(command, Example)
    with pytest.raises(ValueError, match=r"Again\.rate: the command has that setting twice"):
        add_options(command, Again)

    @dataclass(frozen=True)
    class Node:
        tuned: float = option(0.5, "a node's flag for the config's field")

    with pytest.raises(SettingsError, match="tuned has a flag of its own: --tuned"):
        replaced(Example(), ["tuned=0.7"], taken=Node)


def test_every_command_builds_its_flags():
    for command in COMMANDS:
        parser(command)  # a setting twice, or a type without its parse, raises here


def test_every_variable_compose_gives_a_service_is_one_its_command_reads():
    """compose.yaml is a promise: each VOXSHAPE_* variable a service is given is named in its
    command's help (the generated flags' or the bus's), so a renamed setting cannot drop one."""
    services = yaml.safe_load((ROOT / "compose.yaml").read_text())["services"]
    read_elsewhere = {"VOXSHAPE_LOG_FORMAT"}  # voxshape/runtime/logs.py, every command
    missing = []
    for name, body in services.items():
        command = body["command"]
        if command[0] != "voxshape":
            continue
        named = _variables_in_help(command[1]) | read_elsewhere
        for variable in body.get("environment") or {}:
            if variable.startswith("VOXSHAPE_") and variable not in named:
                missing.append(f"{name}: {variable}")
    assert not missing, missing


def _variables_in_help(command: str) -> set[str]:
    sub = next(
        action.choices[command]
        for action in parser(command)._actions
        if isinstance(action, argparse._SubParsersAction)
    )
    return set(re.findall(r"VOXSHAPE_[A-Z_]+", sub.format_help()))


FIVE = 'velocities={"stop": [0, 0], "forward": [0.5, 0], "back": [-0.3, 0], "left": [0.3, 1], %s}'
REFUSED = [
    ("traces=replace", 'traces "replace" is not one of replacing, accumulating'),
    ("potential=bias", 'potential "bias" is not one of straight_line, oracle, none'),
    (
        'velocities={"left": [0.3, 1.0]}',
        "velocities takes every key of stop, forward, back, left, right "
        "(missing stop, forward, back, right)",
    ),
    (
        FIVE % '"right": [0.3, -1], "jump": [1, 1]',
        "velocities takes every key of stop, forward, back, left, right (not jump)",
    ),
    (FIVE % '"right": [0.3]', "velocities[right] takes 2 values, not [0.3]"),
    (FIVE % '"right": [0.3, "x"]', 'velocities[right][1] takes a float, not "x"'),
    ("max_hold=2.5", "max_hold takes an int, like 20, not 2.5"),
    ("use_sonar=1", "use_sonar takes a bool, like true, not 1"),
    ('distance_edges=[1, "far"]', 'distance_edges[1] takes a float, not "far"'),
    ("ask.stuck_s=soon", 'stuck_s takes a float, like 10.0, not "soon"'),
]


@pytest.mark.parametrize(("setting", "error"), REFUSED)
def test_a_setting_out_of_its_type_is_refused_naming_what_is_allowed(setting, error):
    with pytest.raises(SettingsError, match=re.escape(f"--set {setting!r}: {error}")):
        with_settings([setting])


def test_a_whole_dict_and_the_choices_of_a_literal_are_taken():
    config = with_settings(["traces=accumulating", FIVE % '"right": [0.2, -1]'])
    assert config.traces == "accumulating"
    assert config.velocities["right"] == (0.2, -1.0) and config.velocities["stop"] == (0.0, 0.0)


@pytest.mark.parametrize("setting", [s for s, _ in REFUSED[:3]])
def test_the_experiment_command_refuses_a_bad_setting_in_one_line(setting, tmp_path):
    """The real command: exit 2 before any run, one line naming the setting and the choices."""
    argv = [VOXSHAPE, "experiment", "paper", "--set", setting, "--out", str(tmp_path / "out")]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    error = dict(REFUSED)[setting]
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [f"voxshape experiment: --set {setting!r}: {error}"]
    assert not (tmp_path / "out").exists()


def test_a_record_reads_back_as_the_settings_it_was(tmp_path):
    config = with_settings(["alpha=0.1", "traces=accumulating", "ask.stuck_s=3", "near_range=null"])
    assert from_record(LearnerConfig, json.loads(json.dumps(record(config))), "x") == config
    assert from_record(LearnerConfig, {}, "x") == LearnerConfig()  # written before a field was
    write_settings(tmp_path, "learner", config)
    write_settings(tmp_path, "other", Inner(level=2))  # another section, kept beside it
    assert read_settings(tmp_path, "learner", LearnerConfig) == config
    assert read_settings(tmp_path, "other", Inner) == Inner(level=2)
    assert read_settings(tmp_path / "none", "learner", LearnerConfig) is None


def test_a_record_with_a_setting_since_removed_still_reads():
    """ask.open_s became the protocol's QUESTION_OPEN_S: runs recorded with it still read."""
    written = record(LearnerConfig())
    written["ask"]["open_s"] = 8.0
    assert from_record(LearnerConfig, written, "x") == LearnerConfig()
    with pytest.raises(SettingsError, match="no setting open_t in AskConfig"):
        from_record(LearnerConfig, {"ask": {"open_t": 8.0}}, "x")


@pytest.mark.parametrize(
    ("written", "error"),
    [
        ({"learner": {"traces": "replace"}}, 'learner: traces "replace" is not one of'),
        ({"learner": {"alpah": 0.1}}, "learner: no setting alpah in LearnerConfig"),
        ({"learner": {"ask": {"stuck_s": "x"}}}, "learner ask: stuck_s takes a float"),
        ([1, 2], "not an object of sections"),
    ],
)
def test_a_record_that_does_not_fit_is_refused_naming_it(tmp_path, written, error):
    (tmp_path / SETTINGS_FILE).write_text(json.dumps(written))
    with pytest.raises(SettingsError, match=re.escape(error)):
        read_settings(tmp_path, "learner", LearnerConfig)


@pytest.mark.parametrize("command", ["up", "demo"])
def test_a_session_refuses_a_bad_learner_setting_before_it_starts(command, tmp_path):
    argv = [VOXSHAPE, command, "--compose", str(ROOT / "compose.yaml"), "--set", "potential=bias"]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert done.returncode == 2, done.stdout + done.stderr
    error = f"voxshape {command}: error: --set 'potential=bias': {dict(REFUSED)['potential=bias']}"
    assert done.stderr.strip().splitlines() == [error]
    assert not (tmp_path / "runs").exists()  # nothing started, no run folder made


@pytest.mark.parametrize(
    ("setting", "error"),
    [
        ("alpha=7", "alpha 7 is outside (0, 1]"),  # a learning rate
        ("alpha=0", "alpha 0 is outside (0, 1]"),
        ("lookahead_s=-5", "lookahead_s -5 is outside (0, inf)"),  # a duration
        ("epsilon_start=1.5", "epsilon_start 1.5 is outside [0, 1]"),
    ],
)
def test_a_setting_out_of_its_range_is_refused(setting, error):
    with pytest.raises(SettingsError, match=re.escape(error)):
        with_settings([setting])
    assert with_settings(["alpha=1", "lam=0", "gamma=1"]).alpha == 1.0  # the ends that are in


@pytest.mark.parametrize(
    ("setting", "meant"),
    [
        ("lookahead=banana", "lookahead_s or lookahead_fade or lookahead_weight"),
        ("aplha=0.1", "alpha"),
    ],
)
def test_a_key_mistyped_is_answered_with_the_close_ones(setting, meant):
    key = setting.partition("=")[0]
    with pytest.raises(
        SettingsError, match=re.escape(f"no setting {key!r}; did you mean {meant}?")
    ):
        with_settings([setting])


def subcommand(*names: str) -> argparse.ArgumentParser:
    """The parser of `voxshape NAME [SUBNAME]`."""
    found = parser(only=names[0])
    for name in names:
        (sub,) = [a for a in found._actions if isinstance(a, argparse._SubParsersAction)]
        found = sub.choices[name]
    return found


def undocumented_defaults(command: argparse.ArgumentParser) -> list[str]:
    """The flags of a command whose default (a value, not off or empty) its help leaves out."""
    return [
        action.option_strings[0]
        for action in command._actions
        if action.option_strings
        and action.default not in (None, False, [], (), argparse.SUPPRESS)
        and action.help != argparse.SUPPRESS
        and "default" not in (action.help or "")
    ]


@pytest.mark.parametrize(
    "names", [("experiment", e) for e in ("paper", "sweep", "pool", "distributed")] + [("ros2",)]
)
def test_every_default_of_a_command_is_in_its_help(names):
    assert undocumented_defaults(subcommand(*names)) == []

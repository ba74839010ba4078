"""Settings written once (services/runtime/settings.py): a config dataclass's option fields
become flags with their help, variable and default; read back, a flag overrides its variable,
which overrides the default; `--set` takes only the fields without a flag of their own."""

from __future__ import annotations

import argparse
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest
import yaml

from services.cli import COMMANDS, parser
from services.runtime.settings import (
    ConfigError,
    SettingsError,
    add_options,
    add_settings_argument,
    option,
    read_options,
    replaced,
)
from tests.conftest import ROOT


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
        (["--set", "rat=2"], {}, "use KEY=VALUE with KEY one of inner, loud, mode"),
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
    read_elsewhere = {"VOXSHAPE_LOG_FORMAT"}  # services/runtime/logs.py, every command
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

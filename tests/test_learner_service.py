"""`voxshape learner` on a real bus: it drives a lockstep simulator, takes credited feedback
and commands, checkpoints, and resumes from its checkpoint."""

from __future__ import annotations

import re
import signal
import time
import uuid

import pytest

from tests.conftest import VOXSHAPE, bus_args, collect
from voxshape.protocol import (
    ACTION_NAMES,
    Action,
    Credit,
    CreditedFeedback,
    LearningSummary,
    robot_key,
)
from voxshape.runtime import Node


def feedback(step: int, **kind) -> CreditedFeedback:
    return CreditedFeedback(
        robot="r1",
        credits=(Credit(step=step, weight=1.0),),
        sources=(uuid.uuid4().hex,),
        teachers=("ana",),
        **kind,
    )


def start_learner(spawn, router, session_id, path, representation):
    return spawn(
        [
            VOXSHAPE,
            "learner",
            *bus_args(router, session_id, "learner"),
            "--checkpoint",
            str(path),
            "--checkpoint-every",
            "1",
            "--seed",
            "0",
            "--set",
            f"representation={representation}",
        ],
        text=True,
    )


@pytest.mark.parametrize("representation", ["keys", "pearson"])
def test_learner_drives_the_simulator_learns_from_teachers_and_resumes(
    spawn, router, session_id, client_config, tmp_path, representation
):
    path = tmp_path / "learner.npz"
    spawn(
        [
            VOXSHAPE,
            "sim",
            *bus_args(router, session_id, "sim"),
            "--clock",
            "lockstep",
            "--action-timeout",
            "5",
            "--seed",
            "0",
        ]
    )
    learner = start_learner(spawn, router, session_id, path, representation)
    with Node("test", client_config("teacher")) as node:
        node.input("learning", robot_key(session_id, "r1", "learning"))
        node.input("action", robot_key(session_id, "r1", "action"))
        summaries = collect(node, 100, LearningSummary, timeout=30)
        steps = [s.step for s in summaries]
        assert steps == sorted(steps) and len(set(steps)) == len(steps)
        assert summaries[-1].states >= 1 and len(summaries[-1].q_values) == len(ACTION_NAMES)
        out = node.output("feedback", robot_key(session_id, "r1", "feedback"))
        out.put(feedback(steps[-1], kind="reward", reward=50.0, command=None))
        left = ACTION_NAMES.index("left")
        said, taught = 0, []
        while not taught and said < 3:  # an episode that ends as it arrives forgets it
            said += 1
            out.put(feedback(steps[-1], kind="command", command="left", reward=None))
            # every action in order for 3 s: a loaded machine leaves a backlog of them
            until = time.monotonic() + 3.0
            while not taught and time.monotonic() < until:
                action = collect(node, 1, Action)[0]
                if action.chooser == "teacher":
                    taught.append(action)
        assert taught and taught[0].discrete == left
    learner.send_signal(signal.SIGTERM)
    _, err = learner.communicate(timeout=20)
    assert learner.returncode == 0, err
    assert "learner.feedback_credited=1" in err and f"learner.commands={said}" in err
    assert path.is_file()
    states = int(re.search(r"learning robot=r1 .* states=(\d+)", err).group(1))
    assert states == 0  # a fresh start ...
    again = start_learner(spawn, router, session_id, path, representation)
    with Node("test", client_config("watcher")) as node:
        node.input("learning", robot_key(session_id, "r1", "learning"))
        collect(node, 5, LearningSummary, timeout=30)
    again.send_signal(signal.SIGTERM)
    _, err = again.communicate(timeout=20)
    restored = int(re.search(r"learning robot=r1 .* states=(\d+)", err).group(1))
    assert restored >= summaries[-1].states  # ... then resumed with what it had learnt


def test_an_unusable_checkpoint_is_a_clear_error(router, session_id, tmp_path):
    import subprocess

    path = tmp_path / "learner.npz"
    path.write_bytes(b"not a checkpoint")
    result = subprocess.run(
        [VOXSHAPE, "learner", *bus_args(router, session_id, "learner"), "--checkpoint", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2 and "corrupt checkpoint" in result.stderr
    assert "run with --fresh" in result.stderr and "Traceback" not in result.stderr

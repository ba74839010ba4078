"""A learner's checkpoint: restored exactly (the person model and its trail too), a torn
one falls back to the previous, one of other settings or another version refused."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from tests.learner_support import EXACT, KEYS, run_episode
from voxshape.services.learner import checkpoint
from voxshape.services.learner.sarsa import Learner
from voxshape.services.learner.traces import TraceBook

GUESSING = replace(KEYS, potential="straight_line", lookahead_weight=3.0)


@pytest.mark.parametrize("config", [EXACT, KEYS, GUESSING], ids=["pearson", "keys", "guessing"])
def test_checkpoint_round_trip(tmp_path, config):
    learner = Learner(config, seed=3)
    run_episode(learner, TraceBook())
    run_episode(learner, TraceBook())
    learner.way.vote((0.0, 0.0), np.array([0.0, 1.0]), 1.0)  # a word about the way
    path = tmp_path / "learner.npz"
    checkpoint.save(learner, path)
    back = checkpoint.load(path, config)
    assert np.array_equal(back.Q, learner.Q)
    assert back.states.key_of == learner.states.key_of
    assert back.way.tables().keys() == learner.way.tables().keys()
    assert all(
        np.array_equal(a, b)
        for a, b in zip(back.way.tables().values(), learner.way.tables().values(), strict=True)
    )
    assert back.episode == learner.episode
    assert back.rng.random() == learner.rng.random()  # the random stream goes on
    # the same learner: the next episode goes as it would have
    run_episode(back, TraceBook())
    run_episode(learner, TraceBook())
    assert np.array_equal(back.Q, learner.Q)


def test_corrupt_checkpoint_falls_back_to_the_previous_good_one(tmp_path, caplog):
    learner = Learner(EXACT, seed=3)
    path = tmp_path / "learner.npz"
    checkpoint.save(learner, path)  # the good one ...
    run_episode(learner, TraceBook())
    checkpoint.save(learner, path)  # ... becomes .prev
    path.write_bytes(path.read_bytes()[:100])  # torn write
    with pytest.raises(checkpoint.CheckpointError, match="corrupt checkpoint"):
        checkpoint.load(path, EXACT)
    back = checkpoint.load_latest(path, EXACT)
    assert back.episode == 0 and "using the previous one" in caplog.text
    checkpoint.previous(path).write_bytes(b"garbage")
    with pytest.raises(checkpoint.CheckpointError, match=r"learner.prev.npz: corrupt"):
        checkpoint.load_latest(path, EXACT)


def test_checkpoint_of_another_state_representation_is_refused(tmp_path):
    path = tmp_path / "learner.npz"
    checkpoint.save(Learner(EXACT), path)
    with pytest.raises(checkpoint.CheckpointError, match=r"other state settings \(laser_sectors\)"):
        checkpoint.load(path, replace(EXACT, laser_sectors=6))
    assert checkpoint.load_latest(tmp_path / "none.npz", EXACT) is None


def test_a_checkpoint_is_peeked_at_without_restoring_it(tmp_path):
    learner = Learner(EXACT, seed=3)
    run_episode(learner, TraceBook())
    path = tmp_path / "learner.npz"
    checkpoint.save(learner, path)
    assert checkpoint.peek(path) == (learner.episode, len(learner.Q)) != (0, 0)
    path.write_bytes(b"garbage")
    assert checkpoint.peek(path) is None and checkpoint.peek(tmp_path / "none.npz") is None


def test_goal_sectors_must_match_and_checkpoints_of_another_version_are_refused(tmp_path):
    path = tmp_path / "learner.npz"
    learner = Learner(EXACT, seed=0)
    run_episode(learner, TraceBook())
    checkpoint.save(learner, path)
    with pytest.raises(checkpoint.CheckpointError, match=r"other state settings \(goal_sectors\)"):
        checkpoint.load(path, replace(EXACT, goal_sectors=8))
    with np.load(path) as saved:
        arrays = dict(saved)
    meta = json.loads(str(arrays["meta"]))
    meta["version"] = 5  # saved by a build whose words went to an action bias
    np.savez(path, **(arrays | {"meta": np.array(json.dumps(meta))}))
    with pytest.raises(checkpoint.CheckpointError, match=r"version 5, .* start afresh"):
        checkpoint.load(path, EXACT)

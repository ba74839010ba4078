"""Learner checkpoints: one .npz file of arrays plus JSON metadata, no pickle.

Written atomically: the new checkpoint goes to a temporary file that is flushed to disk, the
current one becomes `<name>.prev.npz`, and the temporary file is renamed into place. A crash
at any moment leaves a complete checkpoint behind. On load, a corrupt file is reported and
the previous one used, so at most one checkpoint interval of learning is lost.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import zipfile
from pathlib import Path

import numpy as np

from services.learner.actions import N_ACTIONS
from services.learner.config import LearnerConfig
from services.learner.sarsa import Learner

VERSION = 2
# Settings that decide what a state or an action is: a table learnt with others is useless.
REPRESENTATION = (
    "laser_sectors",
    "use_sonar",
    "goal_features",
    "bearing_bins",
    "distance_edges",
    "clear_range",
    "goal_prior",
)
log = logging.getLogger("voxshape.learner")


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be used; the message names the file and what to do."""


def previous(path: Path) -> Path:
    return path.with_name(path.name.removesuffix(".npz") + ".prev.npz")


def save(learner: Learner, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    config = dataclasses.asdict(learner.config)
    meta = {
        "version": VERSION,
        "episode": learner.episode,
        "counters": dict(learner.counters),
        "config": config,
        "rng": learner.rng.bit_generator.state,
    }
    keys = sorted(learner.states.keys, key=learner.states.keys.get)
    prototypes = (
        np.array(learner.states.prototypes) if learner.states.prototypes else np.zeros((0, 0))
    )
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("wb") as f:
        np.savez(
            f,
            Q=learner.Q,
            H=learner.H,
            Q_goal=learner.Q_goal,
            prototypes=prototypes,
            keys=np.array(keys, dtype=np.int64).reshape(len(keys), 4),
            meta=np.array(json.dumps(meta)),
        )
        f.flush()
        os.fsync(f.fileno())
    if path.exists():
        os.replace(path, previous(path))
    os.replace(tmp, path)


def load(path: Path, config: LearnerConfig, seed: int | None = None) -> Learner:
    """The learner saved at `path`; raises CheckpointError saying what is wrong."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {
                name: data[name] for name in ("Q", "H", "Q_goal", "prototypes", "keys", "meta")
            }
    except FileNotFoundError:
        raise CheckpointError(f"{path}: no such checkpoint") from None
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as e:
        raise CheckpointError(f"{path}: corrupt checkpoint ({type(e).__name__}: {e})") from None
    try:
        meta = json.loads(str(arrays["meta"]))
    except json.JSONDecodeError as e:
        raise CheckpointError(f"{path}: corrupt metadata ({e})") from None
    if meta.get("version") != VERSION:
        raise CheckpointError(
            f"{path}: checkpoint version {meta.get('version')!r}, this "
            f"build reads {VERSION}: start afresh with another file"
        )
    saved = meta["config"]
    ours = dataclasses.asdict(config)
    changed = [k for k in REPRESENTATION if json.loads(json.dumps(ours[k])) != saved.get(k)]
    if changed:
        raise CheckpointError(
            f"{path}: learnt with other state settings ({', '.join(changed)})"
            "; use the same settings or start afresh with another file"
        )
    q, h, keys = arrays["Q"], arrays["H"], arrays["keys"]
    if q.shape != h.shape or q.shape != (len(keys), N_ACTIONS):
        raise CheckpointError(f"{path}: inconsistent tables {q.shape}, {h.shape}, {keys.shape}")
    learner = Learner(config, seed)
    learner.states.restore(arrays["prototypes"], keys)
    if arrays["Q_goal"].shape != learner.Q_goal.shape:
        raise CheckpointError(
            f"{path}: goal table {arrays['Q_goal'].shape}, expected {learner.Q_goal.shape}"
        )
    learner.Q, learner.H, learner.e = q.copy(), h.copy(), np.zeros_like(q)
    learner.Q_goal = arrays["Q_goal"].copy()
    learner.episode = int(meta["episode"])
    learner.counters.update(meta["counters"])
    if seed is None:
        learner.rng.bit_generator.state = meta["rng"]
    return learner


def load_latest(path: Path, config: LearnerConfig, seed: int | None = None) -> Learner | None:
    """The checkpoint at `path`, else the previous one if `path` is corrupt, else None if
    there is none; a corrupt checkpoint with no good previous one raises CheckpointError."""
    if not path.exists() and not previous(path).exists():
        return None
    try:
        return load(path, config, seed)
    except CheckpointError as error:
        if not previous(path).exists():
            raise
        log.error(
            "checkpoint unusable, using the previous one",
            extra={"voxshape_fields": {"error": str(error), "previous": str(previous(path))}},
        )
        return load(previous(path), config, seed)

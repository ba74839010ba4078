"""Learner checkpoints: one .npz file of arrays plus JSON metadata, no pickle.

Written atomically: the new checkpoint goes to a temporary file that is flushed to disk, the
current one becomes `<name>.prev.npz`, and the temporary file is renamed into place. A crash
at any moment leaves a complete checkpoint behind. On load, a corrupt file is reported and
the previous one used, so at most one checkpoint interval of learning is lost.

With the tables (Q and the words' votes and stalls on the way) go the learner's progress on
the bus (`Bookmark`): the last step it learnt from and the ids of the credited feedback it
took (so feedback that a kept output delivers again after a restart is taken once: exactly
the feedback whose effect the tables hold is skipped). The poses a late word is credited to
are not kept: a word about a step before a restart is dropped, counted.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import zipfile
from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from voxshape.services.learner.actions import N_ACTIONS
from voxshape.services.learner.config import LearnerConfig
from voxshape.services.learner.sarsa import Learner
from voxshape.world.maps import Map

VERSION = 6  # 6: words are votes about the way (no H, no recent visits), states are keys
# Settings that decide what a state or an action is: a table learnt with others is useless.
REPRESENTATION = (
    "representation",
    "pearson_threshold",
    "laser_sectors",
    "use_sonar",
    "goal_features",
    "bearing_bins",
    "distance_edges",
    "clear_range",
    "near_range",
    "near_sectors",
    "goal_sectors",
    "way_tile_m",
)
ARRAYS = ("Q", "meta", "vote_tiles", "votes", "stall_tiles", "stalls")
MAX_TAKEN = 4096  # feedback ids remembered: more than a kept feedback output holds
log = logging.getLogger("voxshape.services.learner")


@dataclass
class Bookmark:
    """Where a learner on the bus stands, saved with its tables."""

    step: int | None = None  # the observation step it learnt from last
    taken: OrderedDict[str, None] = field(default_factory=OrderedDict)  # feedback ids

    def first_time(self, feedback_id: str) -> bool:
        """False if that feedback was taken before; remembers it either way."""
        if feedback_id in self.taken:
            return False
        self.taken[feedback_id] = None
        if len(self.taken) > MAX_TAKEN:
            self.taken.popitem(last=False)
        return True

    @classmethod
    def of(cls, step: int | None, taken: Iterable[str]) -> Bookmark:
        return cls(step, OrderedDict.fromkeys(list(taken)[-MAX_TAKEN:]))


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be used; the message names the file and what to do."""


def previous(path: Path) -> Path:
    return path.with_name(path.name.removesuffix(".npz") + ".prev.npz")


def save(learner: Learner, path: Path, progress: Bookmark | None = None) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    progress = progress or Bookmark()
    states = learner.states
    meta = {
        "version": VERSION,
        "episode": learner.episode,
        "counters": dict(learner.counters),
        "config": dataclasses.asdict(learner.config),
        "rng": learner.rng.bit_generator.state,
        "step": progress.step,
        "feedback_taken": list(progress.taken),
        "keys": [list(k) for k in states.key_of],
        "prototypes": [p.tolist() for p in states.prototypes],
    }
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("wb") as f:
        np.savez(f, Q=learner.Q, meta=np.array(json.dumps(meta)), **learner.way.tables())
        f.flush()
        os.fsync(f.fileno())
    if path.exists():
        os.replace(path, previous(path))
    os.replace(tmp, path)


def load(
    path: Path, config: LearnerConfig, seed: int | None = None, task: Map | None = None
) -> Learner:
    """The learner saved at `path`; raises CheckpointError saying what is wrong."""
    return _load(path, config, seed, task)[0]


def _load(
    path: Path, config: LearnerConfig, seed: int | None, task: Map | None
) -> tuple[Learner, Bookmark]:
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            if meta.get("version") != VERSION:
                raise CheckpointError(
                    f"{path}: checkpoint version {meta.get('version')!r}, this "
                    f"build reads {VERSION}: start afresh with another file"
                )
            arrays = {name: data[name] for name in ARRAYS}
    except FileNotFoundError:
        raise CheckpointError(f"{path}: no such checkpoint") from None
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as e:
        raise CheckpointError(f"{path}: corrupt checkpoint ({type(e).__name__}: {e})") from None
    saved, ours = meta["config"], _as_saved(config)
    changed = [k for k in REPRESENTATION if ours[k] != saved.get(k)]
    if changed:
        raise CheckpointError(
            f"{path}: learnt with other state settings ({', '.join(changed)})"
            "; use the same settings or start afresh with another file"
        )
    learner = Learner(config, seed, task)
    learner.states.restore(meta["prototypes"], meta["keys"])
    q = arrays["Q"]
    if q.shape != (len(learner.states), N_ACTIONS):
        raise CheckpointError(
            f"{path}: inconsistent table {q.shape} for {len(learner.states)} states; "
            "start afresh with another file"
        )
    learner.Q, learner.e = q.copy(), np.zeros_like(q)
    learner.way.restore(arrays)
    learner.episode = int(meta["episode"])
    learner.counters.update(meta["counters"])
    if seed is None:
        learner.rng.bit_generator.state = meta["rng"]
    return learner, Bookmark.of(meta.get("step"), meta.get("feedback_taken", []))


def peek(path: Path) -> tuple[int, int] | None:
    """The episodes and features of the checkpoint at `path`, read without restoring it (to
    say what a session resumes); None if there is none or it cannot be read."""
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            return int(meta["episode"]), len(data["Q"])
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile, EOFError):
        return None


def load_latest(
    path: Path, config: LearnerConfig, seed: int | None = None, task: Map | None = None
) -> Learner | None:
    """The checkpoint at `path`, else the previous one if `path` is corrupt, else None if
    there is none; a corrupt checkpoint with no good previous one raises CheckpointError."""
    resumed = resume(path, config, seed, task)
    return resumed[0] if resumed else None


def resume(
    path: Path, config: LearnerConfig, seed: int | None = None, task: Map | None = None
) -> tuple[Learner, Bookmark] | None:
    """`load_latest` with the progress saved beside the tables."""
    if not path.exists() and not previous(path).exists():
        return None
    try:
        return _load(path, config, seed, task)
    except CheckpointError as error:
        if not previous(path).exists():
            raise
        log.error(
            "checkpoint unusable, using the previous one",
            extra={"voxshape_fields": {"error": str(error), "previous": str(previous(path))}},
        )
        return _load(previous(path), config, seed, task)


def _as_saved(config: LearnerConfig) -> dict:
    """A configuration as its checkpoint's JSON reads back (tuples as lists)."""
    return json.loads(json.dumps(dataclasses.asdict(config)))

"""Learner checkpoints: one .npz file of arrays plus JSON metadata, no pickle.

Written atomically: the new checkpoint goes to a temporary file that is flushed to disk, the
current one becomes `<name>.prev.npz`, and the temporary file is renamed into place. A crash
at any moment leaves a complete checkpoint behind. On load, a corrupt file is reported and
the previous one used, so at most one checkpoint interval of learning is lost.

With the tables go the learner's progress on the bus (`Bookmark`): the last step it learnt
from, the ids of the credited feedback it took (so feedback that a kept output delivers again
after a restart is taken once: exactly the feedback whose effect the tables hold is skipped),
and the recent visits late feedback is credited to. Checkpoints without them (older ones) load
with none.
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
from voxshape.services.learner.features import State
from voxshape.services.learner.sarsa import Learner, Visit

VERSION = 5  # 5: no Phi over keys (Phi is over the place), advice over the place too
# Settings that decide what a state or an action is: a table learnt with others is useless.
REPRESENTATION = (
    "representation",
    "tilings",
    "tile_width",
    "heading_tiles",
    "key_tilings",
    "pearson_threshold",
    "advice_generalization",
    "laser_sectors",
    "use_sonar",
    "goal_features",
    "bearing_bins",
    "distance_edges",
    "clear_range",
    "near_range",
    "near_sectors",
    "goal_sectors",
    "advice_place_tilings",
)
PARTS = ("q", "advice", "view")  # a state's features, for Q and H, and its key
# The recent visits: their steps, episode and action weights, and their state's features.
ARRAYS = ("Q", "H", "meta", "visits", "visit_weights", *(f"visit_{p}" for p in PARTS))
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
    config = dataclasses.asdict(learner.config)
    progress = progress or Bookmark()
    meta = {
        "version": VERSION,
        "episode": learner.episode,
        "counters": dict(learner.counters),
        "config": config,
        "rng": learner.rng.bit_generator.state,
        "step": progress.step,
        "feedback_taken": list(progress.taken),
        "features": learner.features.coordinates(),
    }
    visits = list(learner.recent)
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("wb") as f:
        np.savez(
            f,
            Q=learner.Q,
            H=learner.taught.H,
            meta=np.array(json.dumps(meta)),
            visits=np.array([(v.first, v.last, v.episode) for v in visits], dtype=np.int64).reshape(
                len(visits), 3
            ),
            visit_weights=np.array([v.weights for v in visits]).reshape(len(visits), N_ACTIONS),
            **{
                f"visit_{part}": np.array(
                    [getattr(v.state, part) for v in visits] or np.zeros((0, 0)), dtype=np.int64
                )
                for part in PARTS
            },
        )
        f.flush()
        os.fsync(f.fileno())
    if path.exists():
        os.replace(path, previous(path))
    os.replace(tmp, path)


def load(path: Path, config: LearnerConfig, seed: int | None = None) -> Learner:
    """The learner saved at `path`; raises CheckpointError saying what is wrong."""
    return _load(path, config, seed)[0]


def _load(path: Path, config: LearnerConfig, seed: int | None) -> tuple[Learner, Bookmark]:
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
    saved = meta["config"]
    ours = _as_saved(config)
    changed = [k for k in REPRESENTATION if ours[k] != saved.get(k)]
    if changed:
        raise CheckpointError(
            f"{path}: learnt with other state settings ({', '.join(changed)})"
            "; use the same settings or start afresh with another file"
        )
    learner = Learner(config, seed)
    learner.features.restore(meta["features"])
    q, h = arrays["Q"], arrays["H"]
    sizes_ok = (len(q), len(h)) == learner.features.sizes and h.shape[1:] == (N_ACTIONS,)
    if not sizes_ok or q.shape[1:] != (N_ACTIONS,):
        raise CheckpointError(
            f"{path}: inconsistent tables {q.shape}, {h.shape} for "
            f"{learner.features.sizes} features; start afresh with another file"
        )
    learner.Q, learner.e = q.copy(), np.zeros_like(q)
    learner.taught.H = h.copy()
    learner.episode = int(meta["episode"])
    learner.counters.update(meta["counters"])
    if seed is None:
        learner.rng.bit_generator.state = meta["rng"]
    learner.recent.extend(
        Visit(int(first), int(last), int(episode), State(x, advice, int(view)), w.copy())
        for (first, last, episode), w, x, advice, view in zip(
            arrays["visits"],
            arrays["visit_weights"],
            *(arrays[f"visit_{part}"] for part in PARTS),
            strict=True,
        )
    )
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


def load_latest(path: Path, config: LearnerConfig, seed: int | None = None) -> Learner | None:
    """The checkpoint at `path`, else the previous one if `path` is corrupt, else None if
    there is none; a corrupt checkpoint with no good previous one raises CheckpointError."""
    resumed = resume(path, config, seed)
    return resumed[0] if resumed else None


def resume(
    path: Path, config: LearnerConfig, seed: int | None = None
) -> tuple[Learner, Bookmark] | None:
    """`load_latest` with the progress saved beside the tables."""
    if not path.exists() and not previous(path).exists():
        return None
    try:
        return _load(path, config, seed)
    except CheckpointError as error:
        if not previous(path).exists():
            raise
        log.error(
            "checkpoint unusable, using the previous one",
            extra={"voxshape_fields": {"error": str(error), "previous": str(previous(path))}},
        )
        return _load(previous(path), config, seed)


def _as_saved(config: LearnerConfig) -> dict:
    """A configuration as its checkpoint's JSON reads back (tuples as lists)."""
    return json.loads(json.dumps(dataclasses.asdict(config)))

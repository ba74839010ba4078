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

from services.learner.actions import N_ACTIONS
from services.learner.config import LearnerConfig
from services.learner.sarsa import Learner, Visit
from services.learner.states import KEY_FIELDS

VERSION = 2
# Settings that decide what a state or an action is: a table learnt with others is useless.
REPRESENTATION = (
    "laser_sectors",
    "use_sonar",
    "goal_features",
    "bearing_bins",
    "distance_edges",
    "clear_range",
    "near_range",
    "near_sectors",
    "goal_sectors",
)
# What a setting was in checkpoints saved before it was named (when it is not its default).
UNNAMED = {"goal_sectors": 0}
# Representation settings since removed, with the value that means "off": a checkpoint
# learnt with another value is refused.
DROPPED = {"goal_prior": False}
ARRAYS = ("Q", "H", "prototypes", "keys", "meta")
# The recent visits and the potential by place (not in older checkpoints).
OPTIONAL_ARRAYS = ("visits", "visit_weights", "potential")
MAX_TAKEN = 4096  # feedback ids remembered: more than a kept feedback output holds
log = logging.getLogger("voxshape.learner")


@dataclass
class Bookmark:
    """Where a learner on the bus stands, saved with its tables."""

    step: int | None = None  # the observation step it learnt from last
    taken: OrderedDict[str, None] = field(default_factory=OrderedDict)  # feedback ids

    def take(self, feedback_id: str) -> bool:
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
    }
    visits = list(learner.recent)
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
            prototypes=prototypes,
            keys=np.array(keys, dtype=np.int64).reshape(len(keys), len(KEY_FIELDS)),
            meta=np.array(json.dumps(meta)),
            visits=np.array(
                [(v.first, v.last, v.episode, v.state) for v in visits], dtype=np.int64
            ).reshape(len(visits), 4),
            visit_weights=np.array([v.weights for v in visits]).reshape(len(visits), N_ACTIONS),
            potential=np.array(
                [(*place, phi) for place, phi in learner.Phi.items()], dtype=float
            ).reshape(len(learner.Phi), 3),
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
            arrays = {name: data[name] for name in ARRAYS}
            arrays |= {name: data[name] for name in OPTIONAL_ARRAYS if name in data.files}
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
    ours, defaults = (_as_saved(c) for c in (config, LearnerConfig()))
    # A setting a checkpoint does not name was not there yet: it learnt without it.
    changed = [k for k in REPRESENTATION if ours[k] != saved.get(k, UNNAMED.get(k, defaults[k]))]
    dropped = [k for k in DROPPED if saved.get(k, DROPPED[k]) != DROPPED[k]]
    if dropped:
        raise CheckpointError(
            f"{path}: learnt with {', '.join(dropped)}, settings this build no longer has "
            "(docs/decisions.md); start afresh with another file"
        )
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
    learner.Q, learner.H, learner.e = q.copy(), h.copy(), np.zeros_like(q)
    learner.sum_advice_tiles()
    learner.episode = int(meta["episode"])
    learner.counters.update(meta["counters"])
    if seed is None:
        learner.rng.bit_generator.state = meta["rng"]
    for distance, sector, phi in arrays.get("potential", np.zeros((0, 3))):
        learner.Phi[(int(distance), int(sector))] = float(phi)
    visits, weights = arrays.get("visits"), arrays.get("visit_weights")
    if visits is not None and weights is not None and weights.shape == (len(visits), N_ACTIONS):
        learner.recent.extend(
            Visit(int(first), int(last), int(episode), int(state), w.copy())
            for (first, last, episode, state), w in zip(visits, weights, strict=True)
            if 0 <= state < len(q)
        )
    return learner, Bookmark.of(meta.get("step"), meta.get("feedback_taken", []))


def peek(path: Path) -> tuple[int, int] | None:
    """The episodes and states of the checkpoint at `path`, read without restoring it (to
    say what a session resumes); None if there is none or it cannot be read."""
    try:
        with np.load(path, allow_pickle=False) as data:
            meta, keys = json.loads(str(data["meta"])), data["keys"]
            return int(meta["episode"]), len(keys)
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

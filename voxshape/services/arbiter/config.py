"""Every setting of the arbiter, with its default and the reason for it (and, for those with a
flag, its help), and the parsing of the per-teacher flags (`ana=0.5:1.2`, `ana=2`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal, TypeVar

from voxshape.protocol import check_id
from voxshape.protocol.messages import MIN_CONFIDENCE
from voxshape.runtime.settings import ConfigError, option

T = TypeVar("T")
MergePolicy = Literal["sum", "mean", "majority"]
MERGE_POLICIES: tuple[MergePolicy, ...] = ("sum", "mean", "majority")


class ArbiterConfigError(ConfigError):
    """A setting that cannot work; the message names it and the fix."""


@dataclass(frozen=True)
class DelayWindow:
    """Seconds before an utterance's onset in which the teacher saw what they judge: the
    steps displayed then are credited. TAMER's default: 0.2-0.8 s."""

    lo: float = 0.2
    hi: float = 0.8

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lo) and math.isfinite(self.hi)) or not 0 <= self.lo < self.hi:
            raise ArbiterConfigError(
                f"delay window {self.lo:g}:{self.hi:g} needs 0 <= lo < hi (seconds), e.g. 0.2:0.8"
            )
        if self.hi > 10:
            raise ArbiterConfigError(
                f"delay window ends {self.hi:g} s before the onset: at most 10"
            )

    def __str__(self) -> str:
        return f"{self.lo:g}:{self.hi:g}"

    @property
    def centre(self) -> float:
        return (self.lo + self.hi) / 2

    @property
    def width(self) -> float:
        return self.hi - self.lo


def parse_window(text: str) -> DelayWindow:
    """`0.2:0.8` -> DelayWindow(0.2, 0.8)."""
    lo, sep, hi = text.partition(":")
    try:
        if not sep:
            raise ValueError(text)
        bounds = float(lo), float(hi)
    except ValueError:
        raise ArbiterConfigError(
            f"delay window {text!r} is not LO:HI in seconds before the onset, e.g. 0.2:0.8"
        ) from None
    return DelayWindow(*bounds)


def per_teacher(help: str, parse: Callable[[str], T], value: str, example: str) -> Any:
    """A field set by a repeatable flag of `TEACHER=VALUE` items, a dict of each teacher's
    parse(VALUE); a bad item's error says what is wrong, with `example`."""

    def one(item: str) -> tuple[str, T]:
        teacher, sep, value = item.partition("=")
        if not sep:
            raise ArbiterConfigError(f"not TEACHER=VALUE, e.g. {example}")
        return check_id(teacher, "teacher"), parse(value)

    return option(
        help=help,
        default_factory=dict,
        repeat=True,
        metavar=f"TEACHER={value}",
        parse=one,
        collect=dict,
    )


@dataclass(frozen=True)
class DelayLearning:
    """Learning a teacher's reaction delay from their own reactions to salient events (a bump,
    the goal): see credit.ReactionDelay."""

    enabled: bool = True
    pair_within: float = 3.0  # seconds after the event: later reactions are not paired
    min_samples: int = 3  # the configured window is used until this many events agree
    samples: int = 15  # the estimate follows the latest this many events
    tolerance: float = 0.25  # s: reactions this close to the estimate agree with it
    min_half_width: float = 0.05  # half a 10 Hz step: a steady teacher credits one step
    max_half_width: float = 0.6


@dataclass(frozen=True)
class ArbiterConfig:
    """Its fields with a flag are set by it (`--merge mean`), the others by `--set KEY=VALUE`."""

    min_confidence: float = option(
        MIN_CONFIDENCE, "ignore utterances recognized with less (the teacher is asked to repeat)"
    )
    delay: DelayWindow = option(
        help="LO:HI seconds before the onset in which teachers saw what they judge, until "
        "their own delay is learnt",
        default_factory=DelayWindow,
        parse=parse_window,
    )
    teacher_delay: dict[str, DelayWindow] = per_teacher(
        "one teacher's window", parse_window, "LO:HI", "ana=0.5:1.2"
    )
    # Teachers whose delays and rate are in robot seconds, not their own: a simulated teacher
    # watching a simulator that runs faster than real time reacts after as many steps, and
    # says as much per robot second, as at real time (voxshape/services/simteacher). People react in
    # their own seconds whatever the robot's pace.
    robot_time: frozenset[str] = option(
        frozenset(),
        "a teacher whose delays and rate are robot seconds: a simulated teacher on a simulator "
        "faster than real time (people react in their own seconds)",
        env="VOXSHAPE_ROBOT_TIME",
        repeat=True,
        metavar="TEACHER",
        parse=lambda teacher: check_id(teacher, "teacher"),
        collect=frozenset,
    )
    learning: DelayLearning = field(default_factory=DelayLearning)
    merge: MergePolicy = option(
        "sum",
        "several teachers: sum (at once), mean or majority within merge_window",
        env="VOXSHAPE_MERGE",
    )
    merge_window: float = 1.0  # seconds, for mean and majority
    merge_slack_steps: int = 2  # judgements this close in steps are about the same steps
    teacher_weight: dict[str, float] = per_teacher(
        "a teacher's weight; the others weigh 1", float, "W", "ana=2"
    )
    utterances_per_s: float = 4.0  # per teacher, sustained ...
    utterances_at_once: float = 8.0  # ... and at once (a person says at most 2-3 a second)
    remembered_ids: int = 4096  # message ids kept for dropping duplicates
    history_seconds: float = 30.0  # step timing kept per robot (feedback older is too late)
    max_history_steps: int = 20_000  # bound for lockstep sessions (fast steps)
    settle: float = 3.0  # seconds after an episode ends before its interventions are final
    stats_every: float = 1.0  # seconds between statistics updates of a robot
    notice_every: float = 1.0  # rate-limited notices: at most one per teacher per this
    max_teachers: int = 64
    max_robots: int = 64

    def __post_init__(self) -> None:
        if not 0 <= self.min_confidence <= 1:
            raise ArbiterConfigError(f"min confidence {self.min_confidence} is not within [0, 1]")
        if self.merge not in MERGE_POLICIES:
            raise ArbiterConfigError(
                f"merge policy {self.merge!r} is not one of {', '.join(MERGE_POLICIES)}"
            )
        positive = {
            "merge window": self.merge_window,
            "utterances_per_s": self.utterances_per_s,
            "utterances_at_once": self.utterances_at_once,
            "history seconds": self.history_seconds,
        }
        for name, value in positive.items():
            if not (math.isfinite(value) and value > 0):
                raise ArbiterConfigError(f"{name} {value!r} must be a positive number")
        if self.utterances_at_once < 1:
            raise ArbiterConfigError(
                f"utterances_at_once {self.utterances_at_once} must allow at least 1 utterance"
            )
        for teacher, weight in self.teacher_weight.items():
            if not (math.isfinite(weight) and 0 <= weight <= 100):
                raise ArbiterConfigError(
                    f"teacher weight {teacher}={weight} must be within [0, 100]"
                )

    def window_of(self, teacher: str) -> DelayWindow:
        """The configured (not learnt) delay window of a teacher."""
        return self.teacher_delay.get(teacher, self.delay)

    def time_scale(self, teacher: str, pace: float) -> float:
        """Wall seconds per second of the teacher's delays, at the robot's `pace` (wall
        seconds per robot second)."""
        return pace if teacher in self.robot_time else 1.0

    def weight_of(self, teacher: str) -> float:
        return self.teacher_weight.get(teacher, 1.0)

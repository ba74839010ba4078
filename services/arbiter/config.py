"""Every setting of the arbiter, with its default and the reason for it, and the parsing of the
per-teacher flags (`ana=0.5:1.2`, `ana=2`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal, TypeVar

from protocol import ProtocolError, check_id
from protocol.messages import MIN_CONFIDENCE
from services.runtime import ConfigError

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

    @property
    def centre(self) -> float:
        return (self.lo + self.hi) / 2

    @property
    def width(self) -> float:
        return self.hi - self.lo


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
    min_confidence: float = MIN_CONFIDENCE  # below: ignored, the teacher asked to repeat
    delay: DelayWindow = field(default_factory=DelayWindow)
    teacher_delay: dict[str, DelayWindow] = field(default_factory=dict)
    # Teachers whose delays and rate are in robot seconds, not their own: a simulated teacher
    # watching a simulator that runs faster than real time reacts after as many steps, and
    # says as much per robot second, as at real time (services/teacher/simulated). People react in
    # their own seconds whatever the robot's pace.
    robot_time: frozenset[str] = frozenset()
    learning: DelayLearning = field(default_factory=DelayLearning)
    merge: MergePolicy = "sum"
    merge_window: float = 1.0  # seconds, for mean and majority
    merge_slack_steps: int = 2  # judgements this close in steps are about the same steps
    teacher_weight: dict[str, float] = field(default_factory=dict)  # default 1
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


def parse_per_teacher(
    items: list[str] | None, parse: Callable[[str], T], what: str, example: str
) -> dict[str, T]:
    """`["ana=0.5:1.2", ...]` -> {"ana": parse("0.5:1.2")}; names the bad item and the fix."""
    parsed: dict[str, T] = {}
    for item in items or []:
        teacher, sep, value = item.partition("=")
        try:
            if not sep:
                raise ValueError(f"not TEACHER=VALUE, e.g. {example}")
            check_id(teacher, "teacher")
            parsed[teacher] = parse(value)
        except (ProtocolError, ValueError) as e:
            raise ArbiterConfigError(f"{what} {item!r}: {e}") from None
    return parsed


def parse_teachers(items: list[str] | None, what: str) -> frozenset[str]:
    """Teacher ids; names the bad one."""
    for teacher in items or []:
        try:
            check_id(teacher, "teacher")
        except ProtocolError as e:
            raise ArbiterConfigError(f"{what} {teacher!r}: {e}") from None
    return frozenset(items or [])

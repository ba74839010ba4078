"""Every hyper-parameter of the learner, in one place, with the values used in experiments."""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field
from typing import ClassVar, Literal

from voxshape.runtime.settings import add_settings_argument as add_setting
from voxshape.runtime.settings import replaced

# Numbers' ranges: (lowest, highest); "(": the lowest itself refused. Others are unbounded.
RANGES: dict[str, tuple[str, float, float]] = {
    "alpha": ("(", 0.0, 1.0),  # a learning rate
    "gamma": ("(", 0.0, 1.0),
    "lam": ("[", 0.0, 1.0),
    "epsilon_start": ("[", 0.0, 1.0),
    "epsilon_end": ("[", 0.0, 1.0),
    "lookahead_fade": ("[", 0.0, 1.0),
    "word_fade": ("[", 0.0, 1.0),
    "lookahead_s": ("(", 0.0, math.inf),  # a duration
    "judged_s": ("(", 0.0, math.inf),
    "feedback_window_s": ("(", 0.0, math.inf),
    "way_tile_m": ("(", 0.0, math.inf),  # a length
    "temperature": ("(", 0.0, math.inf),
    "converge_slack": ("(", 0.0, math.inf),
    "lookahead_weight": ("[", 0.0, math.inf),
    "guess_weight": ("[", 0.0, math.inf),
    "potential_scale": ("[", 0.0, math.inf),
    "stall_s": ("[", 0.0, math.inf),
    "min_judged_move": ("[", 0.0, math.inf),
    "dead_zone": ("[", 0.0, 180.0),  # degrees
    "command_turn": ("[", 0.0, 180.0),
    "command_aim": ("[", 0.0, 180.0),
    "min_hold": ("[", 1, math.inf),  # steps
    "max_hold": ("[", 1, math.inf),
    "command_steps": ("[", 1, math.inf),
    "converge_episodes": ("[", 1, math.inf),
}


@dataclass(frozen=True)
class AskConfig:
    """When the robot asks "which way?" (asking.py); how long a question is open is the
    protocol's (QUESTION_OPEN_S)."""

    # Settings since removed: a record that still has them reads (open_s: QUESTION_OPEN_S).
    RETIRED: ClassVar[tuple[str, ...]] = ("open_s",)

    per_robot_minute: float = 0.5  # questions a robot minute at most; 0: never asks
    stuck_s: float = 10.0  # robot seconds without progress (or bumping) before asking
    bumps: int = 3  # this many bumps within stuck_s is stuck too
    late_share: float = 0.5  # of the episode's timeout
    flat: float = 1e-6  # Q(s) spread below this, and no word spoken there: unsure
    # Once it has reached the goal, it asks only in episodes this many times longer than its
    # fastest (0: wherever).
    beyond_fastest: float = 2.0

    def __post_init__(self) -> None:
        if self.per_robot_minute < 0 or self.stuck_s <= 0:
            raise ValueError("need per_robot_minute >= 0 and stuck_s > 0")


@dataclass(frozen=True)
class LearnerConfig:
    """The learner's settings; docs/learner.md explains them and docs/decisions.md records
    the measurements behind the defaults."""

    # -- state representation (states.py) -------------------------------------------------
    # "keys": a table over the key (near bits and goal bins); "pearson": the paper's, keys
    # with Pearson prototypes of the sensor readings.
    representation: Literal["keys", "pearson"] = "keys"
    # Pearson prototypes (after Millan et al. 2002): a reading whose best correlation with
    # the prototypes is below the threshold is a new prototype.
    laser_sectors: int = 12  # the 180 beams summarised as the nearest range per sector
    use_sonar: bool = True  # append the 8 rear sonar ranges to the sensor vector
    pearson_threshold: float = 0.9
    goal_features: bool = True  # add the quantised goal bearing and distance to the state
    bearing_bins: int = 8  # 45 degrees each, the first centred straight ahead
    distance_edges: tuple[float, ...] = (1.0, 2.5)  # metres: bins [0,1) [1,2.5) [2.5,inf)
    # Which side of the goal the robot is on: sectors of the world-frame direction from the
    # goal to the robot (heading + bearing). 0: off.
    goal_sectors: int = 8
    # Which of the laser's near_sectors (right to left) has something nearer than this
    # (metres): Pearson's correlation ignores scale. None: off.
    near_range: float | None = 0.6
    near_sectors: int = 3
    # A new state starts with its nearest state's Q (a Pearson prototype's).
    init_from_neighbour: bool = True
    # Readings with nothing nearer than this (metres) share one "clear" prototype. None: off.
    clear_range: float | None = 1.0

    # -- actions ----------------------------------------------------------------------------
    # (v m/s, omega rad/s) of each discrete action; names are protocol.ACTION_NAMES.
    velocities: dict[str, tuple[float, float]] = field(
        default_factory=lambda: {
            "stop": (0.0, 0.0),
            "forward": (0.5, 0.0),
            "back": (-0.3, 0.0),
            "left": (0.3, math.radians(60)),  # arcs: turning on the way, not on the spot
            "right": (0.3, -math.radians(60)),
        }
    )
    # The actions the policy chooses among; the others are left to teachers' commands.
    policy_actions: tuple[str, ...] = ("forward", "left", "right")
    blend: bool = False  # send the softmax-weighted mix of the actions (Millan et al.)
    # The blend's temperature, in units of the state's Q spread (max - min).
    temperature: float = 0.2

    # -- SARSA(lambda) ------------------------------------------------------------------------
    alpha: float = 0.2  # learning rate
    gamma: float = 0.999  # discount per control step (0.1 s): about 100 s ahead
    lam: float = 0.8  # trace decay (lambda)
    # A policy action goes on while the state stays the same, at least min_hold and at most
    # max_hold steps (1 and 1: decide at every step).
    max_hold: int = 20
    min_hold: int = 3
    traces: Literal["replacing", "accumulating"] = "replacing"
    # Epsilon-greedy exploration, decaying linearly from epsilon_start to epsilon_end over
    # epsilon_episodes episodes.
    epsilon_start: float = 0.05
    epsilon_end: float = 0.01
    epsilon_episodes: int = 60

    # -- the way to the goal: the robot's guess and a person's words (way.py, words.py) ------
    # The guess: a potential Phi over the place. Every update's reward gains its rise along
    # the believed way (F = gamma^k Phi(s') - Phi(s) where nobody spoke: potential-based
    # shaping, which keeps the optimum), and the policy looks ahead along it.
    # "straight_line": minus the straight line to the goal; "oracle": minus the map's true
    # shortest way (needs the map: the ceiling of a guess over places); "none": no guess.
    potential: Literal["straight_line", "oracle", "none"] = "straight_line"
    potential_scale: float = 40.0  # reward per metre of progress
    # The policy also ranks each action by the progress along the believed way it makes
    # within lookahead_s (as far as the laser shows it free), times lookahead_weight and
    # potential_scale, fading by lookahead_fade each episode (0: off).
    lookahead_weight: float = 3.0
    lookahead_s: float = 1.0
    lookahead_fade: float = 0.97
    # A person's words are votes about the way (words.py): the guess weighs guess_weight
    # votes, less where it has kept the robot stalled (stall_s seconds of stall halve it);
    # votes are tile-coded over way_tile_m metres and, with the stalls, fade by word_fade
    # each episode; where they turn the way less than dead_zone degrees from the guess, the
    # guess stands.
    guess_weight: float = 3.0
    way_tile_m: float = 2.0
    stall_s: float = 10.0
    word_fade: float = 0.9
    dead_zone: float = 30.0
    # A judgement votes on the motion of the judged_s up to the step the arbiter credits, if
    # the robot moved at least min_judged_move metres and bumped into nothing (stuck or
    # bumping is bad whatever the way); a "left" or "right" votes for the heading
    # command_turn degrees aside of the robot's when the person decided it.
    judged_s: float = 1.0
    min_judged_move: float = 0.15
    command_turn: float = 90.0
    command_aim: float = 20.0  # degrees from the heading the person saw that a turn turns to
    command_steps: int = 5  # a teacher command overrides the policy this many steps
    feedback_window_s: float = 60.0  # robot seconds of poses kept: older credit is dropped

    # -- convergence (see convergence.py) ---------------------------------------------------
    converge_episodes: int = 3  # K consecutive goal episodes ...
    converge_margin: float = 0.25  # ... the slowest within (1 + margin) x the fastest ...
    converge_slack: float = 2.5  # ... and within this many times the map's shortest time

    # -- asking (asking.py): on where the learner runs with a live teacher --------------------
    ask: AskConfig = field(default_factory=AskConfig)

    def __post_init__(self) -> None:
        for name, (bracket, low, high) in RANGES.items():
            value = getattr(self, name)
            if not (low < value <= high or (bracket == "[" and value == low)):
                end = "]" if high < math.inf else ")"
                raise ValueError(f"{name} {value:g} is outside {bracket}{low:g}, {high:g}{end}")
        unknown = set(self.policy_actions) - set(self.velocities)
        if unknown:
            raise ValueError(f"policy_actions {sorted(unknown)}: not in velocities")

    @property
    def top_speed(self) -> float:
        """m/s of the fastest action."""
        return max(abs(v) for v, _ in self.velocities.values())

    def epsilon(self, episode: int) -> float:
        """The chance of a random action after `episode` episodes."""
        done = min(1.0, episode / max(1, self.epsilon_episodes))
        return self.epsilon_start + done * (self.epsilon_end - self.epsilon_start)


def add_settings_argument(parser: argparse.ArgumentParser) -> None:
    add_setting(parser, "voxshape/services/learner/config.py", "alpha=0.1")


def with_settings(settings: list[str], base: LearnerConfig | None = None) -> LearnerConfig:
    """`base` (by default LearnerConfig()) with `--set KEY=VALUE` settings applied."""
    return replaced(base or LearnerConfig(), settings)

"""Every hyper-parameter of the learner, in one place, with the values used in experiments."""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field
from typing import ClassVar, Literal

from voxshape.runtime.settings import add_settings_argument as add_setting
from voxshape.runtime.settings import replaced

# The fields of a state's key (states.py).
KEY_FIELDS = ("prototype", "near", "bearing", "distance", "sector")

# Numbers' ranges: (lowest, highest); "(": the lowest itself refused. Others are unbounded.
RANGES: dict[str, tuple[str, float, float]] = {
    "alpha": ("(", 0.0, 1.0),  # a learning rate
    "gamma": ("(", 0.0, 1.0),
    "lam": ("[", 0.0, 1.0),
    "epsilon_start": ("[", 0.0, 1.0),
    "epsilon_end": ("[", 0.0, 1.0),
    "bias_decay": ("(", 0.0, 1.0),
    "lookahead_s": ("(", 0.0, math.inf),  # a duration
    "judged_s": ("(", 0.0, math.inf),
    "temperature": ("(", 0.0, math.inf),
    "converge_slack": ("(", 0.0, math.inf),
    "min_hold": ("[", 1, math.inf),
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
    flat: float = 1e-6  # Q(s) spread below this, and no advice: unsure
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

    # -- state representation (features.py) ----------------------------------------------
    # "tiles": tile coding of the pose plus the key below; "keys": a table over the key
    # (near bits and goal bins); "pearson": the paper's, keys with Pearson prototypes.
    representation: Literal["tiles", "keys", "pearson"] = "keys"
    tilings: int = 8  # offset grids over (x, y, heading)
    tile_width: float = 1.0  # metres of a tile's side
    heading_tiles: int = 8  # headings per turn in a tiling
    key_tilings: int = 32  # the key's weight in a tiled state, as this many tilings of it
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
    # A new state starts with its nearest state's Q (a Pearson prototype's), a new tile with
    # the value its state has from its other features.
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

    # -- dynamic reward shaping (R = R_RL + R_U) ---------------------------------------------
    # "additive": the paper's r <- g(r, f), the teacher's rewards in Q. "action_bias"
    # (TAMER+RL): they go to a table H and the policy ranks Q + bias_weight * H.
    shaping: Literal["additive", "action_bias"] = "action_bias"
    feedback_bound: float = 100.0  # g(r, f) = r + clip(f, -bound, bound)
    command_reward: float = 10.0  # h(r, a) = r + command_reward for a teacher's action
    command_steps: int = 5  # a teacher command overrides the policy this many steps
    feedback_window: int = 100  # decisions kept for late feedback; older credit is dropped
    bias_weight: float = 10.0  # beta, the weight of H in the policy (action_bias)
    # ... of which the words' H weighs bias_decay^episode, the traces' T always 1 (advice.py)
    bias_decay: float = 0.97
    # With "keys": fields of the key the advice generalizes over, one coarse tiling per
    # field ignoring it; the policy's H(s) is the mean of the state's own and its tiles'.
    advice_generalization: tuple[str, ...] = ("distance", "sector")
    # With "keys": H also reads this many tilings of the pose (x, y, heading; tile_width,
    # heading_tiles), so advice speaks for where and which way the robot was (0: off).
    advice_place_tilings: int = 8

    # The potential Phi over the place (potential.py); every update's reward gains
    # F = gamma^k Phi(s') - Phi(s) (potential-based shaping, which keeps the optimum), and the
    # policy looks ahead along it. "straight_line": minus the straight line to the goal;
    # "oracle": minus the map's true shortest path (experiments only: the ceiling of a
    # potential over places); "none": neither.
    potential: Literal["straight_line", "oracle", "none"] = "straight_line"
    potential_scale: float = 40.0  # reward per metre of Phi
    # The policy also ranks each action by the progress Phi expects of it: beta_Phi times
    # potential_scale times Phi(where a leads within lookahead_s, as far as the laser shows
    # it free) - Phi(here), fading with bias_decay as the words' advice does (0: off).
    lookahead_weight: float = 3.0
    lookahead_s: float = 1.0
    # A judging word's credit is spread over the decisions of the stretch it judges: the
    # judged_s of robot time up to the step the arbiter credits (the person's last look).
    judged_s: float = 1.0

    # -- convergence (see convergence.py) ---------------------------------------------------
    converge_episodes: int = 3  # K consecutive goal episodes ...
    converge_margin: float = 0.25  # ... the slowest within (1 + margin) x the fastest ...
    converge_slack: float = 2.5  # ... and within this many times the map's shortest time

    # -- initial traces ---------------------------------------------------------------------
    # Replay the teacher's traces again every this many episodes; 0: once, before learning
    # (replayed again, their advice adds up where the key aliases places: decisions.md).
    replay_every: int = 0

    # -- asking (asking.py): on where the learner runs with a live teacher --------------------
    ask: AskConfig = field(default_factory=AskConfig)

    def __post_init__(self) -> None:
        for name, (bracket, low, high) in RANGES.items():
            value = getattr(self, name)
            if not (low < value <= high or (bracket == "[" and value == low)):
                end = "]" if high < math.inf else ")"
                raise ValueError(f"{name} {value:g} is outside {bracket}{low:g}, {high:g}{end}")
        if self.representation not in ("tiles", "keys", "pearson"):
            raise ValueError(f"representation {self.representation!r}: one of tiles, keys, pearson")
        if self.tilings < 1 or self.tile_width <= 0 or self.heading_tiles < 1:
            raise ValueError("need tilings >= 1, tile_width > 0 metres, heading_tiles >= 1")
        unknown = set(self.advice_generalization) - set(KEY_FIELDS)
        if unknown:
            raise ValueError(
                f"advice_generalization {sorted(unknown)}: name fields of the state, of "
                f"{', '.join(KEY_FIELDS)}"
            )

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

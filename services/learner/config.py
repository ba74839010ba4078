"""Every hyper-parameter of the learner, in one place, with the values used in experiments."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from dataclasses import dataclass, field
from typing import Literal, TypeVar

# The fields of a state's key (states.py).
KEY_FIELDS = ("prototype", "near", "bearing", "distance", "sector")


@dataclass(frozen=True)
class LearnerConfig:
    # -- state representation (Pearson prototypes, after Millan et al. 2002) ---------------
    laser_sectors: int = 12  # the 180 beams summarised as the nearest range per sector
    use_sonar: bool = True  # append the 8 rear sonar ranges to the sensor vector
    # Best correlation below this: a new prototype is born. None: one prototype, the state is
    # the near bits and the goal bins alone. None by default: on task 2 (300 s episodes,
    # 150 at most) 0.3, 0.6 and 0.9 made 5-10x more states and reached the goal in up to 80%
    # of the late episodes but did not converge; without prototypes tasks 1-3 converged.
    pearson_threshold: float | None = None
    goal_features: bool = True  # add the quantised goal bearing and distance to the state
    bearing_bins: int = 8  # 45 degrees each, the first centred straight ahead
    distance_edges: tuple[float, ...] = (1.0, 2.5)  # metres: bins [0,1) [1,2.5) [2.5,inf)
    # Which side of the goal the robot is on, in this many sectors of the world-frame
    # direction from the goal to the robot (odometry's heading + the bearing): with the
    # distance bins a coarse polar grid around the goal, so the two sides of a wall differ
    # where the straight line to the goal crosses it. 0: off. Measured (10 seeds each, with
    # the teacher's action bias below): the teacher's advice can then say "up along this
    # wall" on one side and "down" on the other; with feedback, task 4 took 33 robot minutes
    # instead of 63, task 3 31 instead of 29; plain RL moves both ways (task 4 101 instead of
    # 208, task 3 186 instead of 103, task 1 35 instead of 16).
    goal_sectors: int = 8
    # Pearson's correlation ignores scale: a wall 2 m ahead and one 0.3 m ahead look alike.
    # So the state also says which of the laser's right, front and left thirds has something
    # nearer than this (metres): what decides whether moving on or turning hits it. None: off.
    near_range: float | None = 0.6
    near_sectors: int = 3  # the laser's sectors with a near bit each, right to left
    init_from_neighbour: bool = True  # a new state starts with its nearest state's Q-values
    # Also learn values per goal cell alone and add them to the state's (two tilings): what is
    # learnt about heading for the goal then holds in every state of that cell at once. Off:
    # where the straight line to the goal crosses walls (tasks 2-4) it pulled the wrong way.
    goal_prior: bool = False
    # Readings with nothing nearer than this (metres) share one "clear" prototype: the shape
    # of far walls says nothing about where to go, and would multiply the states. None: off.
    clear_range: float | None = 1.0

    # -- actions ----------------------------------------------------------------------------
    # (v m/s, omega rad/s) of each discrete action; names are protocol.ACTION_NAMES.
    velocities: dict[str, tuple[float, float]] = field(
        default_factory=lambda: {
            "stop": (0.0, 0.0),
            "forward": (0.5, 0.0),
            "back": (-0.3, 0.0),
            "left": (0.0, math.radians(60)),
            "right": (0.0, -math.radians(60)),
        }
    )
    # The policy chooses among these. "stop" is left to teachers: standing still never
    # earns anything under R_RL (-1 per step), so exploring it only wastes episodes. So is
    # "back": the state has no sensor behind (near bits are the laser's, ahead), and backing
    # blind made the most bumps (44 of 131 early on); a bump's recoil (services/sim/world.py)
    # leaves room to turn instead. Measured (2 seeds, T1-T4): every run converged without it;
    # with it plain RL on task 2 took 250-360 robot minutes with feedback.
    policy_actions: tuple[str, ...] = ("forward", "left", "right")
    # Send the softmax-weighted mix of the actions (Millan et al.) instead of one action.
    # Off by default: on task 1, discrete actions converged in 3 of 3 seeds (50-99 episodes),
    # the blend in 0 of 1 within 200 (benchmarks/plain_rl.py --blend compares them).
    blend: bool = False
    temperature: float = 0.2  # of the blend, in units of the state's Q spread (max - min):
    # an action half the spread below the best gets exp(-0.5 / 0.2) = 8% of the best's weight

    # -- SARSA(lambda) ------------------------------------------------------------------------
    alpha: float = 0.2  # learning rate
    # Discount per control step (0.1 s): 0.999 sees about 100 s ahead. At 0.98 a goal 22 s
    # away was worth 0.98^220 = 1% of its reward, and plain RL never found task 2's goal.
    gamma: float = 0.999
    lam: float = 0.8  # trace decay (lambda)
    # A policy action goes on until the state changes, at most this many steps (1: decide at
    # every step). States are coarse: deciding inside one sees no progress, only -1 per step.
    max_hold: int = 20
    # ... and at least this many steps, even if the state changes sooner: on the edge of two
    # bearing bins (or near bits) one step flips the state, and deciding again at once made
    # the robot turn back and forth there. Measured (10 seeds, four tasks, robot minutes):
    # 3 against 1: RL 79 against 106, RL + F 22.4 against 22.7, perfect advice 15.5
    # against 19.6; 5: 112, 28.2 and 17.9 (a bump is held too).
    min_hold: int = 3
    # May the policy undo its own turn at once (left right after left)? Two states on either
    # side of a bin's edge could each rank the turn towards the other first: the robot turned
    # back and forth on the spot for 10 s and more, its values falling by about 1 a visit,
    # until the teacher scolded it (task 4). Without, a turn goes on, or the robot moves on.
    # Measured (10 seeds, four-task means, robot minutes) against True: plain RL 66.2 against
    # 79.2 (task 2 66.5 against 101.7), RL + F 11.8 against 20.6 (task 4 17.6 against 35.4),
    # RL + T + F 10.3 against 11.1, perfect advice 11.4 against 10.7.
    turn_back: bool = False
    traces: Literal["replacing", "accumulating"] = "replacing"
    # Epsilon-greedy exploration, decaying linearly ... Zero initial values are optimistic
    # (R_RL is -1 a step), which explores by itself; a random action is held until the state
    # changes (max_hold), so 0.2 kept late episodes 2-15x slower than the converged ones.
    epsilon_start: float = 0.05
    epsilon_end: float = 0.01  # ... to this ...
    epsilon_episodes: int = 60  # ... over this many episodes

    # -- dynamic reward shaping (R = R_RL + R_U) ---------------------------------------------
    # "additive": the paper's r <- g(r, f), the teacher's rewards in Q. "action_bias" (TAMER+RL):
    # they go to a table H of their own and the policy ranks Q + beta H. Measured over the four
    # tasks (10 seeds, 20% noise): with feedback 30 robot minutes on average instead of 44.
    # Additive shaping is unlearnt as the teacher falls silent: Q of the way it was praised
    # for sinks to its R_RL value, below the untried actions' optimistic 0, and the robot
    # wanders off the way it had found (task 3: the goal in 28 s at episode 10, timeouts at
    # 17-24). H only changes when the teacher speaks, so what it taught stays.
    shaping: Literal["additive", "action_bias"] = "action_bias"
    feedback_bound: float = 100.0  # g(r, f) = r + clip(f, -bound, bound)
    command_reward: float = 10.0  # h(r, a) = r + command_reward for a teacher's action
    command_steps: int = 5  # a teacher command overrides the policy this many steps
    feedback_window: int = 100  # steps kept for late feedback; older credit is dropped
    # action_bias: the policy ranks Q + beta * H, beta = bias_weight * bias_decay ** episode.
    # H sums the teacher's credits, so advice said often weighs more. Measured on tasks 3-4
    # (rl+f, 10 seeds): beta 1, 3, 10 took 30/74, 29/63 and 31/65 robot minutes; decaying
    # (0.97 per episode) 62 on task 3, as bad as additive: the advice must not fade.
    bias_weight: float = 3.0
    bias_decay: float = 1.0
    # The advice generalizes: a coarse tiling of the states per field named here, each
    # ignoring that field (states.py), and the policy's H(s, .) is the mean of the state's
    # own advice and its tiles' (what was said in every state of the tile). What the teacher
    # said at one distance then speaks for that side of the goal at every distance, and on
    # one side for every side at that distance: a state entered for the first time is no
    # longer advice-blind. () is off. Measured (`voxshape experiment paper`, robot minutes,
    # four-task means, seeds 0-9 | 10-19): RL + F 20.6 | 13.4 against 22.4 | 24.4 (one run of
    # 40 did not converge: it reached the goal in nearly every episode, in 24-60 s, never
    # three alike), RL + T + F 11.1 | 12.8 against 14.7 | 16.6, perfect advice 10.7 | 13.6
    # against 15.5 | 14.7. Plain RL does not use H.
    # Other tilings (survey, seeds 0-9, RL + F / RL + T + F / perfect; the default 17.6 /
    # 11.1 / 10.7 there): one tile ignoring both 18.4 / 12.5 / 13.2; ignoring the distance
    # alone 19.3 / 13.3 / 11.5; ignoring the distance in two tilings, the second's sectors
    # offset by half a sector, 16.7 / 12.6 / 10.7 but 16.0 / 10.6 / 17.5 on seeds 10-19.
    advice_generalization: tuple[str, ...] = ("distance", "sector")

    # -- convergence (see convergence.py) ---------------------------------------------------
    converge_episodes: int = 3  # K consecutive goal episodes ...
    converge_margin: float = 0.25  # ... the slowest within (1 + margin) x the fastest ...
    converge_slack: float = 2.5  # ... and within this many times the map's shortest time

    # -- initial traces ---------------------------------------------------------------------
    replay_every: int = 10  # replay the teacher's traces again every this many episodes (0: once)
    # action_bias: replaying a trace also runs the Q update over the teacher's route. Off: the
    # trace teaches H alone. With it, the route's actions got their true values (-50 to -100
    # at the start, R_RL being -1 a step), below the untried actions' optimistic 0 in the
    # same states, so the robot left the route it had just been shown to try them.
    # Measured (10 seeds, four-task means, robot minutes) against True: RL + T + F 9.2
    # against 10.3, perfect advice 8.1 against 11.4 (task 4 12.4 against 21.6).
    trace_values: bool = False

    def __post_init__(self) -> None:
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
        done = min(1.0, episode / max(1, self.epsilon_episodes))
        return self.epsilon_start + done * (self.epsilon_end - self.epsilon_start)


class SettingsError(ValueError):
    """A `--set KEY=VALUE` that does not fit the configuration."""


def add_settings_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a hyper-parameter of services/learner/config.py, e.g. alpha=0.1",
    )


def with_settings(settings: list[str], base: LearnerConfig | None = None) -> LearnerConfig:
    """`base` (by default LearnerConfig()) with `--set KEY=VALUE` settings applied."""
    return replaced(base or LearnerConfig(), settings)


Config = TypeVar("Config")


def replaced(config: Config, settings: list[str], flag: str = "--set") -> Config:
    """The dataclass `config` with `KEY=VALUE` settings applied (values in JSON: 0.1, true,
    "replacing", [1.0, 2.5]; KEY.FIELD=VALUE sets a field of a nested dataclass); raises
    SettingsError naming an unknown key, a value of the wrong type or one the dataclass
    refuses (`flag` names the option in the message)."""
    items = []
    for setting in settings:
        key, sep, raw = setting.partition("=")
        items.append((setting, key if sep else "", raw))  # no "=": no key, refused below
    return _replaced(config, items, flag)


def _replaced(config: Config, items: list[tuple[str, str, str]], flag: str) -> Config:
    """`replaced` over (the setting as given, KEY, VALUE) items."""
    fields = {f.name: f for f in dataclasses.fields(config)}
    changes = {}
    for setting, key, raw in items:
        outer, dot, inner = key.partition(".")
        if dot and outer in fields and dataclasses.is_dataclass(getattr(config, outer)):
            nested = changes.get(outer, getattr(config, outer))
            changes[outer] = _replaced(nested, [(setting, inner, raw)], flag)
            continue
        if key not in fields:
            raise SettingsError(
                f"{flag} {setting!r}: use KEY=VALUE with KEY one of {', '.join(sorted(fields))}"
            )
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw  # a bare word: a string
        current = getattr(config, key)
        if dataclasses.is_dataclass(current):
            names = ", ".join(f.name for f in dataclasses.fields(current))
            raise SettingsError(
                f"{flag} {setting!r}: {key} is not a single value; set its fields as "
                f"{key}.FIELD=VALUE, FIELD one of {names}"
            )
        if isinstance(current, tuple) and isinstance(value, list):
            value = tuple(value)
        if type(value) is int and "float" in str(fields[key].type):  # float, float | None
            value = float(value)
        ok = (
            type(value) is type(current)
            or (current is None and isinstance(value, float))
            or (value is None and "None" in str(fields[key].type))
        )
        if not ok:
            raise SettingsError(
                f"{flag} {setting!r}: {key} takes a {type(current).__name__}, "
                f"like {json.dumps(current)}"
            )
        changes[key] = value
    try:
        return dataclasses.replace(config, **changes)
    except ValueError as e:
        raise SettingsError(f"{flag}: {e}") from None

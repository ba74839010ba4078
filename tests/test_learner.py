"""The learner's core: the SARSA(lambda) update by hand, state birth, the blend of actions,
late feedback reaching exactly its steps, commands, traces and checkpoints."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tests.learner_support import (
    EXACT,
    FORWARD,
    LEFT,
    WALL_LEFT,
    WALL_RIGHT,
    P,
)
from voxshape.lab.experiment.inprocess import RunSpec, run
from voxshape.protocol import ACTION_NAMES, ProtocolError
from voxshape.runtime import ConfigError
from voxshape.runtime.settings import SettingsError
from voxshape.services.learner import node as learner_node
from voxshape.services.learner.actions import ActionSet
from voxshape.services.learner.config import LearnerConfig, with_settings
from voxshape.services.learner.sarsa import Learner
from voxshape.services.learner.states import CLEAR, StateSpace
from voxshape.services.learner.traces import TraceBook


def test_the_update_against_a_hand_computed_two_step_example():
    learner = Learner(EXACT, seed=0)
    forward, left = learner.actions.one_hot(FORWARD), learner.actions.one_hot(LEFT)
    learner.step(P(WALL_LEFT, step=0), forced=forward)  # s = A: nothing to learn yet
    learner.step(P(WALL_RIGHT, reward=-1.0, step=1), forced=left)  # s' = B
    a, b = 0, 1
    # delta1 = -1 + 0.9 * Q(B, left) - Q(A, forward) = -1; e(A, fwd) = 1
    assert learner.Q[a, FORWARD] == pytest.approx(0.5 * -1.0)
    assert learner.e[a, FORWARD] == pytest.approx(0.9 * 0.8)
    learner.step(P(WALL_LEFT, reward=99.0, outcome="goal", step=2))  # terminal
    # delta2 = 99 + 0 - Q(B, left) = 99; e(B, left) = 1, e(A, fwd) = 0.72
    assert learner.Q[b, LEFT] == pytest.approx(0.5 * 99.0)
    assert learner.Q[a, FORWARD] == pytest.approx(-0.5 + 0.5 * 99.0 * 0.72)
    assert learner.episode == 1 and learner.s is None and not learner.e.any()


def test_a_timeout_bootstraps_from_the_next_state_a_goal_does_not():
    learner = Learner(EXACT, seed=0)
    forward, left = learner.actions.one_hot(FORWARD), learner.actions.one_hot(LEFT)
    learner.step(P(WALL_LEFT, step=0), forced=forward)  # A
    learner.step(P(WALL_RIGHT, step=1), forced=left)  # B; Q(A, fwd) = -0.5
    learner.step(P(WALL_LEFT, step=2, outcome="goal", reward=20.0))
    # Q(B, left) = 0.5 * 20 = 10; Q(A, fwd) = -0.5 + 0.5 * 20 * 0.72 = 6.7
    learner.step(P(WALL_LEFT, step=3), forced=forward)  # a new episode, from A
    learner.step(P(WALL_RIGHT, step=4, outcome="timeout"))  # cut short in B
    # delta = -1 + 0.9 * Q(B, greedy = left) - Q(A, fwd) = -1 + 9 - 6.7 = 1.3, where a
    # terminal state would give -1 + 0 - 6.7 = -7.7
    assert learner.Q[0, FORWARD] == pytest.approx(6.7 + 0.5 * 1.3)
    assert learner.episode == 2 and learner.s is None and not learner.e.any()


def test_accumulating_traces_add_up():
    learner = Learner(replace(EXACT, traces="accumulating"), seed=0)
    forward = learner.actions.one_hot(FORWARD)
    for step in range(3):  # the same state-action three times
        learner.step(P(WALL_LEFT, step=step), forced=forward)
    # e after two updates: (1 * 0.72 + 1) * 0.72; replacing would give 0.72
    assert learner.e[0, FORWARD] == pytest.approx((0.72 + 1) * 0.72)


def test_a_policy_action_goes_on_for_min_hold_steps_even_if_the_state_changes():
    config = replace(EXACT, max_hold=20, min_hold=3)
    learner = Learner(config, seed=0)
    first = learner.step(P(WALL_LEFT, step=0))
    flickers = [learner.step(P(wall, step=k)) for k, wall in enumerate([WALL_RIGHT, WALL_LEFT], 1)]
    assert all(d is first for d in flickers)  # held through the states' flicker
    assert learner.counters["decisions"] == 1 and not learner.Q.any()
    learner.step(P(WALL_RIGHT, step=3))  # held 3 steps: now the state change counts
    assert learner.counters["decisions"] == 2
    assert learner.Q[0].any()  # one update over the 3 steps, from the state it started in


@pytest.mark.parametrize(
    ("turned_by", "epsilon", "undone"),
    [
        ("policy", 0.0, False),
        ("policy", 1.0, False),  # nor does exploration
        ("teacher", 0.0, True),  # a teacher's turn may be undone
    ],
)
def test_the_policy_does_not_undo_its_own_turn_at_once(turned_by, epsilon, undone):
    right = ACTION_NAMES.index("right")
    on_the_spot = {**EXACT.velocities, "left": (0.0, 1.0), "right": (0.0, -1.0)}
    config = replace(EXACT, epsilon_start=epsilon, epsilon_end=epsilon, velocities=on_the_spot)
    learner = Learner(config, seed=0)
    assert learner.actions.undoing == {LEFT: right, right: LEFT}
    assert Learner(EXACT, seed=0).actions.undoing == {}  # arcs move on: no turn undoes one
    learner.step(P(WALL_RIGHT, step=0))  # state 0: B, where turning right looks best by far
    learner.interrupt()
    learner.Q[0, [FORWARD, LEFT, right]] = (-5.0, -5.0, 10.0)
    taken = []
    for k in range(0, 40, 2):  # turned left in A, then in B: right, at once?
        learner.step(P(WALL_LEFT, step=k), forced=learner.actions.one_hot(LEFT, turned_by))
        taken.append(learner.step(P(WALL_RIGHT, step=k + 1)).discrete)
        learner.Q[0, [FORWARD, LEFT, right]] = (-5.0, -5.0, 10.0)
    assert (right in taken) == undone


def test_near_bits_tell_a_wall_close_ahead_from_one_far_ahead():
    space = StateSpace(replace(EXACT, representation="keys", near_range=0.6))
    far, _ = space.classify(P(tuple([2.0] * 180)))
    close_ahead, _ = space.classify(P(tuple([2.0] * 60 + [0.4] * 60 + [2.0] * 60)))
    close_left, _ = space.classify(P(tuple([2.0] * 120 + [0.4] * 60)))
    assert len({far, close_ahead, close_left}) == 3  # Pearson alone: all alike in shape
    assert space.classify(P(tuple([3.0] * 180)))[0] == far
    assert space.near_bits(P(tuple([2.0] * 60 + [0.4] * 60 + [2.0] * 60))) == 0b010


def test_states_are_born_from_pearson_correlation():
    space = StateSpace(replace(EXACT, pearson_threshold=0.9))
    a, _ = space.classify(P(WALL_LEFT))
    same_shape, _ = space.classify(P(tuple(2 * r for r in WALL_LEFT)))  # farther, same shape
    other, parent = space.classify(P(WALL_RIGHT))
    assert a == same_shape == 0 and other == 1 and len(space.prototypes) == 2
    assert parent == a  # its nearest state: best-matching prototype, same goal bins


def test_goal_features_split_states_and_can_be_switched_off():
    space = StateSpace(EXACT)
    ahead, _ = space.classify(P(WALL_LEFT, goal_bearing=0.1))
    behind, _ = space.classify(P(WALL_LEFT, goal_bearing=math.pi - 0.1))
    near, _ = space.classify(P(WALL_LEFT, goal_bearing=0.1, goal_distance=0.5))
    assert len({ahead, behind, near}) == 3 and len(space.prototypes) == 1
    blind = StateSpace(replace(EXACT, goal_features=False))
    assert (
        blind.classify(P(WALL_LEFT, goal_bearing=0.1))[0]
        == blind.classify(P(WALL_LEFT, goal_bearing=3.0, goal_distance=9.0))[0]
    )


def test_a_clear_view_is_one_state():
    space = StateSpace(replace(EXACT, clear_range=1.0))
    a, _ = space.classify(P(tuple([3.0] * 180)))
    b, _ = space.classify(P(tuple([1.5] * 90 + [6.0] * 90)))
    assert a == b and not space.prototypes and next(iter(space.keys))[0] == CLEAR


def test_a_new_state_starts_from_its_nearest_neighbour():
    learner = Learner(replace(EXACT, pearson_threshold=0.999), seed=0)
    first = learner._state_of(P(WALL_LEFT))
    learner.Q[first] = [1, 2, 3, 4, 5]
    similar = tuple([0.5] * 60 + [3.0] * 120)  # correlated, but below the threshold
    second = learner._state_of(P(similar))
    assert second != first and list(learner.q(second)) == [1, 2, 3, 4, 5]
    elsewhere = learner._state_of(P(similar, goal_bearing=3.0))  # no neighbour with these bins
    assert list(learner.q(elsewhere)) == [0, 0, 0, 0, 0]


def test_the_blend_weights_actions_by_q_and_credits_them_by_weight():
    actions = ActionSet(LearnerConfig(blend=True))
    rng = np.random.default_rng(0)
    q = np.array([0.0, 10.0, 0.0, 8.0, 0.0])  # stop forward back left right
    decision = actions.choose(q, epsilon=0.0, rng=rng)
    w = decision.weights
    assert w[0] == w[2] == 0.0  # stop and back are for teachers only
    assert w[1] > w[3] > w[4] > 0 and w.sum() == pytest.approx(1.0)
    assert w[3] / w[1] == pytest.approx(math.exp(-2.0 / (0.2 * 10.0)))
    assert decision.v == pytest.approx(w @ actions.velocity[:, 0])
    assert decision.omega == pytest.approx(w @ actions.velocity[:, 1]) and decision.omega > 0
    flat = actions.choose(np.zeros(5), epsilon=0.0, rng=rng)
    assert sorted(flat.weights) == [0, 0, 0, 0, 1]  # nothing learnt: one action, no mush
    with_back = ActionSet(LearnerConfig(blend=True, policy_actions=("forward", "back", "left")))
    assert with_back.choose(q, epsilon=0.0, rng=rng).weights[2] > 0
    discrete = ActionSet(LearnerConfig(blend=False)).choose(q, epsilon=0.0, rng=rng)
    assert discrete.discrete == 1 and discrete.weights.max() == 1.0


def test_a_command_overrides_the_policy_and_earns_nothing_in_r():
    learner = Learner(EXACT, seed=0)
    learner.step(P(WALL_LEFT, step=0))
    learner.command("left")
    taken = [learner.step(P(WALL_LEFT, step=k)) for k in range(1, 1 + EXACT.command_steps)]
    assert all(d.chooser == "teacher" and d.discrete == LEFT for d in taken)
    assert learner.step(P(WALL_LEFT, step=9)).chooser == "policy"
    assert learner.Q[0, LEFT] < 0  # -1 per step: a word is a vote about the way, not a reward


def test_a_trace_counts_the_words_a_person_says_to_dictate_it():
    learner, book = Learner(EXACT, seed=0), TraceBook()
    commands = ["left"] * 7 + ["forward"] * 3 + ["left"]  # left twice, forward, left
    for step, command in enumerate([*commands, None]):
        if command:
            learner.command(command)
        end = command is None
        p = P(WALL_LEFT, outcome="goal" if end else "running", step=step)
        book.record(p, learner.step(p))
    assert book.words(command_steps=5) == 2 + 1 + 1
    assert book.words(command_steps=1) == len(commands)


def test_traces_keep_the_pose_and_one_without_it_shows_no_way(tmp_path):
    student = Learner(replace(EXACT, goal_sectors=8), seed=0)
    left = student.actions.one_hot(LEFT, "teacher")
    book = TraceBook()
    for step, theta in enumerate((0.0, math.pi / 2, math.pi)):
        end = step == 2
        p = P(WALL_LEFT, theta=theta, outcome="goal" if end else "running", step=step, x=step)
        book.record(p, None if end else left)
    book.save(tmp_path / "traces.npz")
    loaded = TraceBook.load(tmp_path / "traces.npz")
    assert [p.theta for p, _ in loaded.episodes[0]] == [0.0, math.pi / 2, math.pi]
    assert [p.x for p, _ in loaded.episodes[0]] == [0.0, 1.0, 2.0] and loaded.poses
    with np.load(tmp_path / "traces.npz") as z:  # a file saved with headings alone
        arrays = {k: z[k] for k in z.files if k != "pose"}
        np.savez(tmp_path / "old.npz", **arrays, theta=z["pose"][:, 2])
    old = TraceBook.load(tmp_path / "old.npz")
    assert not old.poses and [p.theta for p, _ in old.episodes[0]] == [0.0, math.pi / 2, math.pi]
    assert [p.x for p, _ in old.episodes[0]] == [0.0] * 3
    assert loaded.show(student) == 1 and old.show(student) == 0  # no place: no way shown


def test_the_learner_service_drives_every_robot_each_with_its_own_checkpoint():
    environ = {"VOXSHAPE_ROBOTS": "r1, r2,r1", "VOXSHAPE_ROBOT": "r9"}
    assert learner_node.robots_of(None, environ) == ("r1", "r2")  # as the simulator's list
    assert learner_node.robots_of(["r3"], environ) == ("r3",)  # --robot wins
    assert learner_node.robots_of(None, {"VOXSHAPE_ROBOT": "r9"}) == ("r9",)
    assert learner_node.robots_of(None, {}) == ("r1",)
    with pytest.raises(ProtocolError):
        learner_node.robots_of(["a b"], {})
    assert learner_node.checkpoint_path(None, "s", "r2", 2) == Path("runs/s/learner-r2.npz")
    assert learner_node.checkpoint_path(Path("x.npz"), "s", "r1", 1) == Path("x.npz")
    template = Path("ckpt/{robot}.npz")
    assert learner_node.checkpoint_path(template, "s", "r2", 2) == Path("ckpt/r2.npz")
    with pytest.raises(ConfigError, match=r"put \{robot\} in it"):
        learner_node.checkpoint_path(Path("x.npz"), "s", "r1", 2)


def test_plain_sarsa_lambda_learns_task_1_within_a_bounded_number_of_episodes():
    result = run(RunSpec("1", "rl", seed=1, max_episodes=80))  # the defaults, no teacher
    print(
        f"task 1, seed 1: converged={result.converged} after {result.episodes} episodes, "
        f"{result.learning_time_s / 60:.1f} min of robot time, {result.states} states"
    )
    assert result.converged and result.episodes <= 80
    last = result.outcomes[-LearnerConfig().converge_episodes :]
    assert last == ["goal"] * len(last)


def test_settings_from_the_command_line_are_typed_and_checked():
    config = with_settings(
        ["alpha=0.05", "blend=true", "traces=accumulating", "distance_edges=[1, 3]", "max_hold=3"]
    )
    assert (config.alpha, config.blend, config.traces, config.distance_edges, config.max_hold) == (
        0.05,
        True,
        "accumulating",
        (1, 3),
        3,
    )
    optional = with_settings(["clear_range=2", "near_range=null"])  # float | None fields
    assert (optional.clear_range, optional.near_range) == (2.0, None)
    assert type(optional.clear_range) is float
    with pytest.raises(SettingsError, match="KEY is one of"):
        with_settings(["alhpa=0.1"])
    with pytest.raises(SettingsError, match="blend takes a bool"):
        with_settings(["blend=3"])


def test_the_summary_reports_the_episode_return():
    learner = Learner(EXACT, seed=0)
    forward = learner.actions.one_hot(FORWARD)
    learner.step(P(WALL_LEFT, step=0), forced=forward)
    learner.step(P(WALL_RIGHT, reward=-1.0, step=1), forced=forward)
    learner.step(P(WALL_LEFT, reward=99.0, outcome="goal", step=2))
    assert learner.episode_return == 98.0  # kept until the next episode starts
    learner.step(P(WALL_LEFT, step=3), forced=forward)
    assert learner.episode_return == 0.0


def test_convergence_is_k_steady_goal_episodes_and_time_is_robot_time():
    from voxshape.services.learner.convergence import Convergence, EpisodeResult

    progress = Convergence(LearnerConfig(converge_episodes=3, converge_margin=0.25))
    history = [
        ("timeout", 600, 0),
        ("goal", 100, 2),
        ("goal", 200, 1),
        ("goal", 120, 0),
        ("goal", 110, 1),
        ("goal", 124, 0),
        ("goal", 300, 0),
    ]
    done = [progress.add(EpisodeResult(o, n, n * 0.1, i)) for o, n, i in history]
    # converged at the 6th: of the last three (120, 110, 124) the slowest is within 125% of
    # the fastest
    assert done == [False, False, False, False, False, True, True]
    assert progress.n_episodes == 6 and progress.interventions == 4
    assert progress.learning_time == pytest.approx((600 + 100 + 200 + 120 + 110 + 124) * 0.1)


def test_three_equally_slow_goal_episodes_are_not_convergence_on_a_map():
    from voxshape.services.learner.convergence import Convergence, EpisodeResult, convergence_on
    from voxshape.world.maps import load_map

    config = LearnerConfig(converge_episodes=3, converge_slack=2.5)
    slow = [EpisodeResult("goal", 2400, 240.0)] * 3
    unbounded = Convergence(config)
    assert [unbounded.add(e) for e in slow][-1]  # without the map's bound
    progress = convergence_on(load_map("1"), config)  # task 1: 5.1 m at 0.5 m/s, 10.3 s
    assert progress.shortest_s == pytest.approx(10.3, abs=0.2)
    assert not any(progress.add(e) for e in slow)
    assert [progress.add(EpisodeResult("goal", 200, 20.0)) for _ in range(3)] == [
        False,
        False,
        True,
    ]


def test_goal_sectors_tell_the_sides_of_the_goal_apart():
    """Facing the goal 3 m away from the west and from the east: the same bearing and
    distance, on opposite sides of the goal."""
    west, east = P(WALL_LEFT, theta=0.0), P(WALL_LEFT, theta=math.pi)
    plain = StateSpace(LearnerConfig(goal_sectors=0))
    assert plain.classify(west)[0] == plain.classify(east)[0]
    sided = StateSpace(LearnerConfig(goal_sectors=8))
    assert sided.classify(west)[0] != sided.classify(east)[0]
    assert sided.goal_bins(west)[2] == 4 and sided.goal_bins(east)[2] == 0  # goal -> robot

"""SARSA(lambda) with dynamic rewards: the paper's Algorithm 1, with eligibility traces, and a
robot that believes it knows the way (way.py) until a person's words say otherwise.

One control step (`Learner.step`), with s the previous state and a the action taken in it:

    observe r, s'              r = R_RL, the simulator's reward for the step
    hold a?                    while s' is s (the same key) and nothing was bumped, and for
                               a's first min_hold steps, a goes on: r accumulates as
                               G = sum gamma^i r_i over its k steps, and the update below
                               uses G and gamma^k (SARSA over the states' changes), `_holds`
    choose a' from s'          the teacher's command if one is pending ("if the user selects
                               action a in s"), else epsilon-greedy (or the blend) over Q plus
                               the lookahead: each action's progress along the believed way,
                               never the turn that undoes the policy's own turn, `_select`
    update                     delta = G + F + gamma^k Q(s', a') - Q(s, a), with the shaping
                               F = gamma^k Phi(s') - Phi(s) + the progress along the words'
                               correction of the way (0 where nobody spoke; Q(s', a') and
                               Phi(s') are 0 at a terminal s'; a timeout truncates: it
                               bootstraps); e(s, a) <- 1 (replacing) or e(s, a) + 1;
                               Q <- Q + alpha delta e;  e <- gamma^k lambda e,  `_update`
    s <- s', a <- a'

"If the user provides feedback f on state s', r <- g(r, f)": here a person's words do not
enter r as numbers. Each is evidence about the way (words.py): it turns the believed way
where it contradicts the robot's guess, and the way enters every update through F and every
choice through the lookahead. A word that agrees with the guess changes nothing.

With the blend, a is a mix of the discrete actions with weights w: Q(s, a) is w . Q(s, .)
and each action's trace grows by its weight, so each is credited in proportion to its share.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np

from voxshape.protocol import ACTION_NAMES
from voxshape.services.learner.actions import N_ACTIONS, ActionSet, Decision
from voxshape.services.learner.config import LearnerConfig
from voxshape.services.learner.lookahead import reach, reachable
from voxshape.services.learner.potential import Place, StraightLine, potential_for
from voxshape.services.learner.states import Percept, StateSpace
from voxshape.services.learner.way import Way
from voxshape.services.learner.words import WordCredit
from voxshape.world.maps import Map
from voxshape.world.robot import CONTROL_PERIOD_S


class LearnerPercept(Percept, Protocol):
    x: float  # metres, world frame (odometry)
    y: float
    reward: float  # R_RL of the step that led here
    outcome: str  # "running" unless the episode ended here
    step: int  # the observation's step id (feedback is credited to these)
    collided: bool  # the step that led here bumped into something


# Sees each decision a person's input changed: where the robot is, where the chosen action
# leads, and where the action it would have chosen without the person leads.
ChangeWatcher = Callable[[Place, Place, Place], None]


class Learner:
    def __init__(
        self, config: LearnerConfig | None = None, seed: int | None = None, task: Map | None = None
    ) -> None:
        self.config = c = config or LearnerConfig()
        self.states = StateSpace(c)
        self.actions = ActionSet(c)
        self.Q = np.zeros((0, N_ACTIONS))  # action values, a row per state
        self.e = np.zeros((0, N_ACTIONS))  # eligibility traces
        self.counters: Counter[str] = Counter()
        self.way = Way(potential_for(c.potential, task), c)  # the guess, and the words'
        self.words = WordCredit(c, self.way, self.counters)
        self.rng = np.random.default_rng(seed)
        self.episode = 0  # episodes finished
        self.s: int | None = None  # the previous state ...
        self.a: Decision | None = None  # ... and the action taken in it
        self.place: Place | None = None  # where s was
        self.pose: tuple[float, float, float] | None = None  # where the robot is now
        self.laser: Sequence[float] = ()  # and what its laser sees
        self.commands: deque[int] = deque()  # teacher's actions still to take
        self.aim: tuple[float, float] | None = None  # a commanded turn's heading, and its sign
        self.on_changed: ChangeWatcher | None = None
        self.td_error = 0.0
        self.G, self.discount, self.held = 0.0, 1.0, 0  # the action in progress
        self.episode_return = 0.0

    # -- Algorithm 1 ----------------------------------------------------------------------
    def step(self, p: LearnerPercept, forced: Decision | None = None) -> Decision | None:
        """Learns from the step that led to `p` and returns the action to take next (None
        when the episode ended). `forced` imposes a'."""
        s_next = self._state_of(p)  # observe s'
        place = (float(p.x), float(p.y))
        self.pose, self.laser = (*place, float(p.theta)), p.laser
        guess = self.way.guess
        if isinstance(guess, StraightLine) and guess.goal is None:
            guess.goal = goal_of(p)
        self.way.watch(place, CONTROL_PERIOD_S, new_episode=self.s is None)
        self.words.saw(int(p.step), self.pose, bool(p.collided), self.episode)
        ended = p.outcome != "running"
        if self.s is None:  # the first step of an episode: nothing to learn yet
            self.episode_return = 0.0
        else:
            self._accumulate(p.reward)  # r into the return G
            if self._holds(s_next, ended or p.collided, forced):
                return self.a
        terminal = ended and p.outcome != "timeout"  # a timeout truncates: s' has a future
        # choose a' (on a timeout too: the update bootstraps from Q(s', a'), then a' is dropped)
        a_next = None if terminal else (forced or self._select(s_next))
        if self.s is not None:
            self._update(s_next, place, a_next)
        self.G, self.discount, self.held = 0.0, 1.0, 0
        if ended:
            self._end_episode()
            return None
        self.s, self.a, self.place = s_next, a_next, place
        self.counters["decisions"] += 1
        return a_next

    def _update(self, s_next: int, place: Place, a_next: Decision | None) -> None:
        """The SARSA(lambda) update for (s, a), held k steps for a return G (discount is
        gamma^k), shaped by F = gamma^k Phi(s') - Phi(s) plus the words' correction of the
        way's progress; a_next is None when s' is terminal."""
        c, s, a = self.config, self.s, self.a
        q_next = 0.0 if a_next is None else a_next.weights @ self.Q[s_next]
        phi_next = 0.0 if a_next is None else self.phi(place)
        words = self.way.progress(self.place, place) - self.way.progress(self.place, place, False)
        F = self.discount * phi_next - self.phi(self.place) + c.potential_scale * words
        delta = self.G + F + self.discount * q_next - a.weights @ self.Q[s]
        if c.traces == "replacing":  # e(s, a) <- 1, by each action's weight in a
            self.e[s] = np.maximum(self.e[s], a.weights)
        else:  # e(s, a) <- e(s, a) + 1
            self.e[s] += a.weights
        self.Q += c.alpha * delta * self.e
        self.e *= self.discount * c.lam  # gamma^k lambda after an action held k steps
        self.td_error = float(delta)

    def _accumulate(self, r: float) -> None:
        """Adds the step's reward r to the return G of the action in progress, discounted by
        gamma per step it has been held."""
        self.G += self.discount * r
        self.episode_return += r
        self.discount *= self.config.gamma
        self.held += 1

    def _holds(self, s_next: int, ended: bool, forced: Decision | None) -> bool:
        """Action holding: the policy's action goes on while the state (its key) stays the
        same, and for its first min_hold steps, at most max_hold steps; a teacher's action, a
        forced one, a pending command, a bump or the episode's end make a decision at once."""
        c = self.config
        return (
            (s_next == self.s or self.held < c.min_hold)
            and not ended
            and forced is None
            and not self.commands
            and self.a.chooser == "policy"
            and self.held < c.max_hold
        )

    def _select(self, s: int) -> Decision:
        """a' from s': a pending command, else epsilon-greedy (or the blend) over Q plus the
        lookahead along the believed way, never the turn that undoes the policy's own turn."""
        barred = None
        if self.a is not None and self.a.chooser == "policy":
            barred = self.actions.undoing.get(self.a.discrete)
        alone = self._greedy(self.Q[s] + self._expected_progress(words=False), barred)
        if self.commands and self._aimed():
            self.commands.clear()  # turned as far as the person asked
        if self.commands:
            decision = self.actions.one_hot(self.commands.popleft(), "teacher")
            self._count_change(decision.discrete, alone)
            return decision
        q = self.Q[s] + self._expected_progress()
        decision = self.actions.choose(q, self.config.epsilon(self.episode), self.rng, barred)
        if decision.discrete == self._greedy(q, barred):  # not explored
            self._count_change(decision.discrete, alone)
        return decision

    def _expected_progress(self, words: bool = True) -> np.ndarray | float:
        """What each action makes of the way from here: lookahead_weight fade^episode
        potential_scale times its progress along the believed way (`words=False`: the
        guess's alone) to where it leads within lookahead_s."""
        c = self.config
        if not c.lookahead_weight or self.pose is None:
            return 0.0
        if self.way.guess is None and not (words and self.way.votes):
            return 0.0
        here = self.pose[:2]
        places = reachable(self.pose, self.laser, self.actions.velocity, c.lookahead_s)
        weight = c.lookahead_weight * c.lookahead_fade**self.episode * c.potential_scale
        return weight * np.array([self.way.progress(here, p, words) for p in places])

    def _greedy(self, q: np.ndarray, barred: int | None) -> int:
        allowed = self.actions.allowed_but(barred)
        return int(allowed[np.argmax(q[allowed])])

    def _count_change(self, chosen: int, alone: int) -> None:
        """Counts a decision made by a command or greedily, and whether the person's input
        changed it against what the robot would have done without it (`on_changed` sees
        where each leads)."""
        self.counters["decisions_judged"] += 1
        if chosen == alone:
            return
        self.counters["changed_by_person"] += 1
        if self.on_changed is not None and self.pose is not None:
            velocity, seconds = self.actions.velocity, self.config.lookahead_s
            places = reachable(self.pose, self.laser, velocity, seconds)
            self.on_changed(self.pose[:2], places[chosen], places[alone])

    # -- a teacher's command ---------------------------------------------------------------
    def command(self, action: str, seen_heading: float | None = None) -> None:
        """A teacher's command: the next `command_steps` actions are this one. A turn said
        about the robot heading `seen_heading` (when the person decided it) turns until the
        robot heads `command_aim` degrees aside of that, for at most twice as long: the part
        it has turned since the person looked is not turned again."""
        c = self.config
        turn = {"left": 1.0, "right": -1.0}.get(action)
        self.aim = None
        steps = c.command_steps
        if turn is not None and seen_heading is not None and c.command_aim:
            self.aim = (seen_heading + turn * math.radians(c.command_aim), turn)
            steps *= 2
        self.commands.clear()
        self.commands.extend([ACTION_NAMES.index(action)] * steps)
        self.counters["commands"] += 1

    def _aimed(self) -> bool:
        """Whether a commanded turn has brought the robot to the heading it aims at."""
        if self.aim is None or self.pose is None:
            return False
        target, turn = self.aim
        return turn * math.remainder(target - self.pose[2], math.tau) <= 0

    # -- the values -------------------------------------------------------------------------
    def q(self, s: int) -> np.ndarray:
        """Q(s, .)."""
        return self.Q[s]

    def phi(self, place: Place | None) -> float:
        """Phi at the place the robot was in a state: the guess's metres times
        potential_scale."""
        if place is None:
            return 0.0
        return self.config.potential_scale * self.way.phi(place)

    @property
    def reach(self) -> float | None:
        """How far the sensors must see for this learner (None: their full range)."""
        seen = self.states.reach
        if seen is None or not self.config.lookahead_weight:
            return seen
        return max(seen, reach(self.actions.velocity, self.config.lookahead_s))

    # -- states and episodes ------------------------------------------------------------
    def _state_of(self, p: LearnerPercept) -> int:
        s, parent = self.states.classify(p)
        if s == len(self.Q):  # a new state: a new row, from its nearest state's if asked
            row = self.Q[parent] if self.config.init_from_neighbour and parent is not None else 0
            self.Q = np.vstack([self.Q, np.zeros((1, N_ACTIONS)) + row])
            self.e = np.vstack([self.e, np.zeros((1, N_ACTIONS))])
        return s

    def _end_episode(self) -> None:
        self.interrupt()
        self.episode += 1
        self.way.fade()

    def interrupt(self) -> None:
        """Forgets the episode in progress without counting it (a gap in the observations,
        a replay that stops mid-episode)."""
        self.e[:] = 0.0
        self.s = self.a = self.place = None
        self.commands.clear()
        self.G, self.discount, self.held = 0.0, 1.0, 0


def goal_of(p: LearnerPercept) -> Place:
    """Where the goal is in the world frame, from a percept's pose and its goal fields."""
    heading = p.theta + p.goal_bearing
    return (p.x + p.goal_distance * np.cos(heading), p.y + p.goal_distance * np.sin(heading))

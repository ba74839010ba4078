"""SARSA(lambda) with dynamic rewards: the paper's Algorithm 1, with eligibility traces.

One control step (`Learner.step`), with s the previous state and a the action taken in it:

    observe r, s'              r = R_RL, the simulator's reward for the step; if the teacher
                               selected a, r <- h(r, a) = r + command_reward (bounded)
    hold a?                    while s' looks as s (the same key) and nothing was bumped,
                               and for a's first min_hold steps, a goes on:
                               r accumulates as G = sum gamma^i r_i over its k steps, and
                               the update below uses G and gamma^k (SARSA over the states'
                               changes), `_holds`
    choose a' from s'          the teacher's command if one is pending, else the policy
                               derived from Q (epsilon-greedy, or the blend; plus beta H and
                               the lookahead along the potential Phi), never the turn
                               that undoes the policy's own turn a, `_select`
    update                     delta = G + F + gamma^k Q(s', a') - Q(s, a), with the
                               shaping F = gamma^k Phi(s') - Phi(s)   (0 for Q(s', a') and
                               Phi(s') when s' is terminal; a timeout is a truncation: it
                               bootstraps)
                               e(s, a) <- 1 (replacing) or e(s, a) + 1 (accumulating)
                               Q <- Q + alpha delta e;  e <- gamma^k lambda e,  `_update`
    s <- s', a <- a'

With the blend, a is a mix of the discrete actions with weights w: Q(s, a) is w . Q(s, .)
and each action's trace grows by its weight, so each is credited in proportion to its share.

"If the user provides feedback f on state s', r <- g(r, f)": spoken feedback arrives late,
so the arbiter credits it to past steps with weights, and `credit` applies g's bounded f
after the fact (late credit, which approximates on-time feedback: see its docstring).

Q and H are linear over the state's binary features (features.py): Q(s, .) is the mean of the
rows of Q of s's active features, and e has a row per feature, so the update reads as the
table's (a table is one feature per state) and moves every state sharing a feature. Phi, the
potential, is over the robot's place (potential.py).

Where g's f and h's bonus go is the shaping rule the learner is given (shaping.py): into r
and Q (shaping="additive", the paper's), or, by default, into a table H of their own that the
policy adds to Q (TAMER+RL's action biasing). H(s) is the mean of the rows of H of the state's
advice features, so what was said in a state also speaks for the states sharing one.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from voxshape.protocol import ACTION_NAMES
from voxshape.services.learner.actions import N_ACTIONS, ActionSet, Decision
from voxshape.services.learner.advice import Advice
from voxshape.services.learner.config import LearnerConfig
from voxshape.services.learner.features import PosePercept, State, representation
from voxshape.services.learner.lookahead import reach, reachable
from voxshape.services.learner.potential import Place, Potential, StraightLine
from voxshape.services.learner.shaping import SHAPINGS
from voxshape.services.learner.way import Way
from voxshape.world.robot import CONTROL_PERIOD_S


class LearnerPercept(PosePercept, Protocol):
    reward: float  # R_RL of the step that led here
    outcome: str  # "running" unless the episode ended here
    step: int  # the observation's step id (feedback is credited to these)
    collided: bool  # the step that led here bumped into something


@dataclass
class Visit:
    """A decision of the recent past (steps first..last), kept for late feedback."""

    first: int
    last: int
    episode: int
    state: State
    weights: np.ndarray


class Learner:
    def __init__(self, config: LearnerConfig | None = None, seed: int | None = None) -> None:
        self.config = c = config or LearnerConfig()
        self.features = representation(c)
        self.actions = ActionSet(c)
        self.Q = np.zeros((0, N_ACTIONS))  # action values, a row per feature
        self.e = np.zeros((0, N_ACTIONS))  # eligibility traces, a row per feature of Q
        self.taught = Advice(c)  # H and T, the teacher's action bias
        self.shaping = SHAPINGS[c.shaping](c, self.taught)  # where g's f and h's bonus go
        self.rng = np.random.default_rng(seed)
        self.episode = 0  # episodes finished
        self.s: State | None = None  # the previous state ...
        self.a: Decision | None = None  # ... and the action taken in it
        self.recent: deque[Visit] = deque(maxlen=c.feedback_window)
        # Phi over places: the straight line, or one given (the experiments' oracle)
        self.potential: Potential | None = (
            StraightLine() if c.potential == "straight_line" else None
        )
        self.way = (
            Way(self.potential, c.guess_weight, c.way_tilings, c.way_tile_m)
            if c.shaping == "way"
            else None
        )
        self.trail: deque[tuple[int, float, float, float]] = deque(maxlen=4096)  # poses
        self._best_phi = (-math.inf, 0.0)  # the episode's best Phi, and seconds since
        if self.way is not None:
            self.way.stall_s = c.stall_s
            self.way.agree_cos = math.cos(math.radians(c.dead_zone))
        self.on_changed = (
            None  # called (here, chosen place, unchanged place) when words change a decision
        )
        self.place: Place | None = None  # where s was
        self.pose: tuple[float, float, float] | None = None  # where the robot is now
        self.laser: Sequence[float] = ()  # and what its laser sees
        self.commands: deque[int] = deque()  # teacher's actions still to take
        self.command_chooser = "teacher"
        self.counters: Counter[str] = Counter()
        # The credit of judging words: on the decision each credited step fell in, and in all
        self.credit_shares = np.zeros(2)
        self.td_error = 0.0
        self.G, self.discount, self.held = 0.0, 1.0, 0  # the action in progress
        self.episode_return = 0.0

    # -- Algorithm 1 ----------------------------------------------------------------------
    def step(
        self, p: LearnerPercept, forced: Decision | None = None, replay: bool = False
    ) -> Decision | None:
        """Learns from the step that led to `p` and returns the action to take next (None
        when the episode ended). `forced` imposes a'; `replay`: the step is a teacher's
        trace replayed, not the robot's own (its commands earn h's bonus only additively)."""
        s_next = self._state_of(p)  # observe s'
        place = (float(p.x), float(p.y))
        self.pose = (*place, float(p.theta))
        self.trail.append((int(p.step), *self.pose, bool(p.collided)))
        self.laser = p.laser
        if isinstance(self.potential, StraightLine) and self.potential.goal is None:
            self.potential.goal = goal_of(p)
        if self.way is not None:
            self._watch_progress(place)
        ended = p.outcome != "running"
        if self.s is None:  # the first step of an episode: nothing to learn yet
            self.episode_return = 0.0
        else:
            self._accumulate(p.reward, replay)  # r, and h's bonus, into the return G
            if self._holds(s_next, ended or p.collided, forced):
                self.recent[-1].last = p.step
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
        self.recent.append(Visit(p.step, p.step, self.episode, s_next, a_next.weights))
        self.s, self.a, self.place = s_next, a_next, place
        self.counters["decisions"] += 1
        return a_next

    def _watch_progress(self, place: Place) -> None:
        """Counts the robot's time at a place while the guess sees no progress (Phi has not
        risen `stall_rise` metres within `stall_after` seconds): where it stalls, the guess
        weighs less against the person's words."""
        c = self.config
        phi = self.way.phi(place)
        if self.s is None or phi > self._best_phi[0] + c.stall_rise:
            self._best_phi = (phi, 0.0)
            return
        self._best_phi = (self._best_phi[0], self._best_phi[1] + CONTROL_PERIOD_S)
        if self._best_phi[1] >= c.stall_after:
            self.way.stall(place, CONTROL_PERIOD_S)

    def _update(self, s_next: State, place: Place, a_next: Decision | None) -> None:
        """The SARSA(lambda) update for (s, a), held k steps for a return G (discount is
        gamma^k), shaped by F = gamma^k Phi(s') - Phi(s); a_next is None when s' is
        terminal."""
        c, x = self.config, self.s.q  # x: the features of s
        q_next = 0.0 if a_next is None else a_next.weights @ self.q(s_next)
        phi_next = 0.0 if a_next is None else self.phi(place)
        shaping = self.discount * phi_next - self.phi(self.place)
        if self.way is not None and self.way.votes and c.way_shapes_q:
            rise = self.way.progress(self.place, place)
            shaping += c.potential_scale * (rise - self.way.progress(self.place, place, False))
        delta = self.G + shaping + self.discount * q_next - self.a.weights @ self.q(self.s)
        if c.traces == "replacing":  # e(s, a) <- 1, by each action's weight in a
            self.e[x] = np.maximum(self.e[x], self.a.weights)
        else:  # e(s, a) <- e(s, a) + 1
            self.e[x] += self.a.weights
        self.Q += c.alpha * delta * self.e
        self.e *= self.discount * c.lam  # gamma^k lambda after an action held k steps
        self.td_error = float(delta)

    def _accumulate(self, r: float, replay: bool) -> None:
        """Adds the step's reward r (with h's bonus if the teacher chose a) to the return G
        of the action in progress, discounted by gamma per step it has been held."""
        if self.a.chooser == "teacher":
            r = self._h(r, self.s, self.a, replay)
        self.G += self.discount * r
        self.episode_return += r
        self.discount *= self.config.gamma
        self.held += 1

    def _holds(self, s_next: State, ended: bool, forced: Decision | None) -> bool:
        """Action holding: the policy's action goes on while what the robot sees (the state's
        key) stays the same, and for its first min_hold steps, at most max_hold steps; a
        teacher's action, a forced one, a pending command, a bump or the episode's end make a
        decision at once."""
        c = self.config
        return (
            (s_next.view == self.s.view or self.held < c.min_hold)
            and not ended
            and forced is None
            and not self.commands
            and self.a.chooser == "policy"
            and self.held < c.max_hold
        )

    def _select(self, s: State) -> Decision:
        """a' from s': a pending command, else epsilon-greedy (or the blend) over Q (plus
        beta H with the action bias: the shaping rule's ranking), never the turn that undoes
        the policy's own turn."""
        q_own = self.q(s)
        barred = None
        if self.a is not None and self.a.chooser == "policy":
            barred = self.actions.undoing.get(self.a.discrete)
        alone = self._greedy(q_own + self._expected_progress(words=False), barred)
        if self.commands:
            decision = self.actions.one_hot(self.commands.popleft(), self.command_chooser)
            self._count_change(decision.discrete, alone)
            return decision
        q = self.shaping.ranked(q_own, s, self.episode) + self._expected_progress()
        decision = self.actions.choose(q, self.config.epsilon(self.episode), self.rng, barred)
        if decision.discrete == self._greedy(q, barred):  # not explored
            self._count_change(decision.discrete, alone)
        return decision

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
            velocity, reach_s = self.actions.velocity, self.config.lookahead_s
            places = reachable(self.pose, self.laser, velocity, reach_s)
            self.on_changed(self.pose[:2], places[chosen], places[alone])

    def _expected_progress(self, words: bool = True) -> np.ndarray | float:
        """What the potential expects of each action from here: beta_Phi fade^episode
        potential_scale (Phi(where it leads in lookahead_s) - Phi(here)); with the way, the
        progress along the believed way (`words=False`: the guess's alone)."""
        c = self.config
        if not c.lookahead_weight or self.pose is None:
            return 0.0
        if self.way is None and self.potential is None:
            return 0.0
        places = reachable(self.pose, self.laser, self.actions.velocity, c.lookahead_s)
        weight = c.lookahead_weight * c.bias_decay**self.episode * c.potential_scale
        here = self.pose[:2]
        if self.way is not None:
            return weight * np.array([self.way.progress(here, p, words) for p in places])
        ahead = np.array([self.potential.value(*place) for place in places])
        return weight * (ahead - self.potential.value(*here))

    def _h(self, r: float, s: State, a: Decision, replay: bool) -> float:
        """h(r, a): the reward of an action the teacher selected (bounded like g), in a
        replayed trace or live."""
        return self.shaping.chosen(r, s, a.weights, self._bonus(), replay)

    def _bonus(self) -> float:
        """h's bonus for a teacher's action, bounded like g's f."""
        bound = self.config.feedback_bound
        return float(np.clip(self.config.command_reward, -bound, bound))

    # -- late credit --------------------------------------------------------------------
    def credit(self, step: int, weight: float, f: float) -> bool:
        """Feedback f about the action taken at observation `step`, with the arbiter's weight
        w: g(r, f) = r + clip(f) after the fact, Q <- Q + alpha w f share_j (H with the
        action bias) for each decision j of the stretch the word judges, by its share of
        that stretch (`_stretch_back_from`); the change it would have made to the updates
        since is ignored. False (counted) if `step` has left the window."""
        c = self.config
        f = float(np.clip(f, -c.feedback_bound, c.feedback_bound))
        k = self._decision_at(step)
        if k is None:
            return False
        visits, shares = self._stretch_back_from(k, step)
        self.credit_shares += (shares[0] * weight, weight)
        if self.way is not None:
            self._vote_on_stretch(step, c.judgement_vote * weight * np.sign(f))
            self.counters["feedback_credited"] += 1
            return True
        states, weights = [v.state for v in visits], np.array([v.weights for v in visits])
        scale = c.alpha * weight * f
        self.shaping.credit(self.Q, states, np.array(shares)[:, None] * scale * weights)
        self.counters["feedback_credited"] += 1
        return True

    def _stretch_back_from(self, k: int, step: int) -> tuple[list[Visit], list[float]]:
        """The decisions of the stretch a word judges: those that ran within the `judged_s`
        up to `step` (back from the k-th, in its episode), each with its share of those steps
        (summing to 1)."""
        first = step - round(self.config.judged_s / CONTROL_PERIOD_S) + 1
        episode, visits, shares = self.recent[k].episode, [], []
        for j in range(k, -1, -1):
            visit = self.recent[j]
            if visit.episode != episode or visit.last < first:
                break
            visits.append(visit)
            shares.append(min(visit.last, step) - max(visit.first, first) + 1)
        total = sum(shares)
        return visits, [share / total for share in shares]

    def _pose_at(self, step: int) -> tuple[float, float, float] | None:
        """The robot's pose at observation `step` (the latest before it), if remembered."""
        for entry in reversed(self.trail):
            if entry[0] <= step:
                return entry[1:4]
        return None

    def _bumped_within(self, first: int, last: int) -> bool:
        return any(e[4] for e in self.trail if first <= e[0] <= last)

    def _vote_on_stretch(self, step: int, vote: float) -> None:
        """A judgement's vote on the motion of the judged stretch up to `step`: its
        displacement, or the heading where the robot hardly moved."""
        first = step - round(self.config.judged_s / CONTROL_PERIOD_S)
        end, start = self._pose_at(step), self._pose_at(first)
        if end is None or start is None:
            return
        move = np.subtract(end[:2], start[:2])
        length = float(np.hypot(*move))
        if length < self.config.min_judged_move or self._bumped_within(first, step):
            self.counters["votes_stuck"] += abs(vote)  # stuck or bumping is bad any way round
            return
        middle = ((start[0] + end[0]) / 2, (start[1] + end[1]) / 2)
        rise = self.way.phi(end[:2]) - self.way.phi(start[:2])
        if self.config.agreeing_votes or rise * vote <= 0:  # the guess judged it otherwise
            self.way.vote(middle, move / length, vote)
        else:
            self.counters["votes_agreeing"] += 1

    def _vote_heading(
        self, pose: tuple[float, float, float], action: str, weight: float = 1.0
    ) -> None:
        """A command's vote: the way lies where it turns the robot, from the pose the teacher
        saw (ahead for "forward", behind for "back", `command_turn` degrees aside for a turn)."""
        turn = math.radians(self.config.command_turn)
        aside = {"forward": 0.0, "left": turn, "right": -turn, "back": math.pi}.get(action)
        if aside is None:
            return
        heading = pose[2] + aside
        vote = np.array([math.cos(heading), math.sin(heading)])
        self.way.vote(pose[:2], vote, self.config.command_vote * weight)
        self.counters["votes_command"] += weight

    def shown(self, path: Sequence[tuple[float, float, bool]]) -> None:
        """A way shown whole (a dictated trace that reached the goal, its places and bumps):
        a vote every `trace_vote_m` metres travelled, for the way on from there (towards the
        place `trace_chord_m` further along it, so its wobbles even out); none in the second
        before a bump."""
        c, period = self.config, CONTROL_PERIOD_S
        places = np.array([p[:2] for p in path])
        along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(places, axis=0).T))])
        bumps = [i for i, p in enumerate(path) if p[2]]
        before_bump = {j for i in bumps for j in range(max(0, i - round(1 / period)), i + 1)}
        for metre in np.arange(0.0, along[-1], c.trace_vote_m):
            i = int(np.searchsorted(along, metre))
            j = int(np.searchsorted(along, metre + c.trace_chord_m))
            j = min(j, len(path) - 1)
            move = places[j] - places[i]
            length = float(np.hypot(*move))
            if length > 0.1 and not before_bump.intersection(range(i, j + 1)):
                self.way.vote(tuple(places[i]), move / length, c.trace_vote)

    def _decision_at(self, step: int) -> int | None:
        """The index in `recent` of the decision whose action ran at observation `step`;
        None (counted) if it is no longer remembered."""
        for i in range(len(self.recent) - 1, -1, -1):
            if self.recent[i].first <= step <= self.recent[i].last:
                return i
        oldest = self.recent[0].first if self.recent else None
        why = "too_old" if oldest is not None and step < oldest else "unknown_step"
        self.counters[f"feedback_dropped.{why}"] += 1
        return None

    def command(
        self, action: str, chooser: str = "teacher", credits: Sequence[tuple[int, float]] = ()
    ) -> None:
        """A teacher's command: the next `command_steps` actions are this one (`chooser`:
        "teacher" earns h's bonus, "steer" does not); `credits`, the steps the teacher saw
        when deciding it, with their weights."""
        index = ACTION_NAMES.index(action)
        if self.way is not None and chooser == "teacher":
            for step, weight in credits:
                pose = self._pose_at(step)
                if pose is not None:
                    self._vote_heading(pose, action, weight)
        self.command_chooser = chooser
        self.commands.clear()
        self.commands.extend([index] * self.config.command_steps)
        self.counters["commands"] += 1

    def answer(self, step: int, action: str) -> bool:
        """The teacher's answer to "which way?" asked at observation `step`: the action is
        advised in the state asked in (as h advises a command), and taken now if the robot
        still sees what it saw there (without h: it was advised). False if the step left the
        window."""
        k = self._decision_at(step)
        if k is None:
            return False
        asked = self.recent[k].state
        weights = self.actions.one_hot(ACTION_NAMES.index(action)).weights
        pose = self._pose_at(step)
        if self.way is not None and pose is not None:
            self._vote_heading(pose, action)
        self.shaping.credit(self.Q, [asked], (self.config.alpha * self._bonus() * weights)[None])
        if self.s is not None and self.s.view == asked.view:
            self.command(action, "steer")
        self.counters["answers"] += 1
        return True

    @property
    def reach(self) -> float | None:
        """How far the sensors must see for this learner (None: their full range)."""
        seen = self.features.reach
        if seen is None or not self.config.lookahead_weight or self.potential is None:
            return seen
        return max(seen, reach(self.actions.velocity, self.config.lookahead_s))

    # -- the values, linear over the state's features ---------------------------------------
    def q(self, s: State) -> np.ndarray:
        """Q(s, .): the mean of the rows of Q of the state's features."""
        return self.Q[s.q].sum(axis=0) / len(s.q)

    def advice(self, s: State) -> np.ndarray:
        """The teacher's bias in s as the policy weighs it now (advice.py)."""
        return self.taught.weighed(s, self.episode)

    def phi(self, place: Place | None) -> float:
        """Phi at the place the robot was in a state: the potential's metres times
        potential_scale."""
        if self.potential is None or place is None:
            return 0.0
        return self.config.potential_scale * self.potential.value(*place)

    # -- states and episodes ------------------------------------------------------------
    def _state_of(self, p: LearnerPercept) -> State:
        s, parent = self.features.encode(p)
        n_q, n_advice = self.features.sizes
        if n_q > len(self.Q):  # new features: new rows, from what is known, if asked
            known = s.q[s.q < len(self.Q)]
            row = 0.0
            if self.config.init_from_neighbour and parent is not None:
                row = self.Q[parent]  # a new state: its nearest state's values
            elif self.config.init_from_neighbour and len(known):
                row = self.Q[known].sum(axis=0) / len(known)  # the state's other features'
            self.Q = np.vstack([self.Q, np.zeros((n_q - len(self.Q), N_ACTIONS)) + row])
            self.e = np.vstack([self.e, np.zeros((n_q - len(self.e), N_ACTIONS))])
        self.taught.grow(n_advice)
        return s

    def _end_episode(self) -> None:
        self.interrupt()
        self.episode += 1
        if self.way is not None:
            self.way.fade(self.config.vote_fade, self.config.stall_fade)

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

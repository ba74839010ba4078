"""SARSA(lambda) with dynamic rewards: the paper's Algorithm 1, with eligibility traces.

One control step (`Learner.step`), with s the previous state and a the action taken in it:

    observe r, s'              r = R_RL, the simulator's reward for the step; if the teacher
                               selected a, r <- h(r, a) = r + command_reward (bounded)
    hold a?                    while s' looks as s (the same key), and for a's first
                               min_hold steps, a goes on:
                               r accumulates as G = sum gamma^i r_i over its k steps, and
                               the update below uses G and gamma^k (SARSA over the states'
                               changes), `_holds`
    choose a' from s'          the teacher's command if one is pending, else the policy
                               derived from Q (epsilon-greedy, or the blend), never the turn
                               that undoes the policy's own turn a, `_select`
    update                     delta = G + F + gamma^k Q(s', a') - Q(s, a), with the words'
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

Q, H and Phi are linear over the state's binary features (features.py): Q(s, .) is the mean
of the rows of Q of s's active features, and e has a row per feature, so the update reads as
the table's (a table is one feature per state) and moves every state sharing a feature.

Where g's f and h's bonus go is the shaping rule the learner is given (shaping.py): into r
and Q (shaping="additive", the paper's), or, by default, into a table H of their own that the
policy adds to Q (TAMER+RL's action biasing). H(s) is the mean of the rows of H of the state's
advice features, so what was said in a state also speaks for the states sharing one.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from protocol import ACTION_NAMES, CreditedFeedback
from services.learner.actions import N_ACTIONS, ActionSet, Decision
from services.learner.advice import Advice
from services.learner.config import LearnerConfig
from services.learner.features import PosePercept, State, representation
from services.learner.shaping import SHAPINGS


class LearnerPercept(PosePercept, Protocol):
    reward: float  # R_RL of the step that led here
    outcome: str  # "running" unless the episode ended here
    step: int  # the observation's step id (feedback is credited to these)


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
        self.taught = Advice(c)  # H, the teacher's action bias, and Phi, the words' potential
        self.shaping = SHAPINGS[c.shaping](c, self.taught)  # where g's f and h's bonus go
        self.rng = np.random.default_rng(seed)
        self.episode = 0  # episodes finished
        self.s: State | None = None  # the previous state ...
        self.a: Decision | None = None  # ... and the action taken in it
        self.recent: deque[Visit] = deque(maxlen=c.feedback_window)
        self.commands: deque[int] = deque()  # teacher's actions still to take
        self.command_chooser = "teacher"
        self.counters: Counter[str] = Counter()
        self.td_error = 0.0
        self.G, self.discount, self.held = 0.0, 1.0, 0  # the action in progress
        self.episode_return = 0.0

    # -- Algorithm 1 ----------------------------------------------------------------------
    def step(
        self, p: LearnerPercept, forced: Decision | None = None, replay: bool = False
    ) -> Decision | None:
        """Learns from the step that led to `p` and returns the action to take next (None
        when the episode ended). `forced` imposes a'; `replay`: the step is a teacher's
        trace replayed, not the robot's own (with the action bias it teaches H alone)."""
        s_next = self._state_of(p)  # observe s'
        ended = p.outcome != "running"
        if self.s is None:  # the first step of an episode: nothing to learn yet
            self.episode_return = 0.0
        else:
            self._accumulate(p.reward, replay)  # r, and h's bonus, into the return G
            if self._holds(s_next, ended, forced):  # a goes on: no decision this step
                self.recent[-1].last = p.step
                return self.a
        terminal = ended and p.outcome != "timeout"  # a timeout truncates: s' has a future
        # choose a' (on a timeout too: the update bootstraps from Q(s', a'), then a' is dropped)
        a_next = None if terminal else (forced or self._select(s_next))
        if self.s is not None and (not replay or self.shaping.replays_learn_q):
            self._update(s_next, a_next)
        self.G, self.discount, self.held = 0.0, 1.0, 0
        if ended:
            self._end_episode()
            return None
        self.recent.append(Visit(p.step, p.step, self.episode, s_next, a_next.weights))
        self.s, self.a = s_next, a_next
        self.counters["decisions"] += 1
        return a_next

    def _update(self, s_next: State, a_next: Decision | None) -> None:
        """The SARSA(lambda) update for (s, a), held k steps for a return G (discount is
        gamma^k); a_next is None when s' is terminal."""
        c, x = self.config, self.s.q  # x: the features of s
        q_next = 0.0 if a_next is None else a_next.weights @ self.q(s_next)
        shaping = (0.0 if a_next is None else self.discount * self.phi(s_next)) - self.phi(self.s)
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
        teacher's action, a forced one, a pending command or the episode's end make a
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
        if self.commands:
            return self.actions.one_hot(self.commands.popleft(), self.command_chooser)
        q = self.shaping.ranked(self.q(s), s, self.episode)
        barred = None
        if self.a is not None and self.a.chooser == "policy":
            barred = self.actions.undoing.get(self.a.discrete)
        return self.actions.choose(q, self.config.epsilon(self.episode), self.rng, barred)

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
        w: g(r, f) = r + clip(f) after the fact, Q <- Q + alpha w f e_k (H with the action
        bias), e_k rebuilt from the recent decisions (`_traces_back_from`); the change it
        would have made to the updates since is ignored. False (counted) if `step` has left
        the window."""
        c = self.config
        f = float(np.clip(f, -c.feedback_bound, c.feedback_bound))
        k = self._decision_at(step)
        if k is None:
            return False
        visits, e_k = self._traces_back_from(k)
        states, weights = [v.state for v in visits], np.array([v.weights for v in visits])
        if c.potential_rate:
            self.taught.toward(states, e_k, weight, f)
        scale = c.alpha * weight * f
        self.shaping.credit(self.Q, states, np.array(e_k)[:, None] * scale * weights)
        self.counters["feedback_credited"] += 1
        return True

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

    def _traces_back_from(self, k: int) -> tuple[list[Visit], list[float]]:
        """The decisions back from the k-th in its episode, and e_k(s_j, a_j) =
        (gamma lambda)^(k - j) of each, until it is negligible: a held action decays by
        gamma^k lambda in the update, a revisited state counts once per visit (as
        accumulating traces do)."""
        c, episode = self.config, self.recent[k].episode
        visits, traces, trace = [], [], 1.0
        for j in range(k, -1, -1):
            visit = self.recent[j]
            if visit.episode != episode or trace < 1e-4:
                break
            visits.append(visit)
            traces.append(trace)
            trace *= c.gamma * c.lam
        return visits, traces

    def take(self, feedback: CreditedFeedback) -> list[int]:
        """The arbiter's credited feedback: a command, or a reward credited to its steps;
        returns the steps that had left the window (dropped, counted)."""
        if feedback.kind == "command":
            self.command(feedback.command)
            return []
        return [
            c.step for c in feedback.credits if not self.credit(c.step, c.weight, feedback.reward)
        ]

    def command(self, action: str, chooser: str = "teacher") -> None:
        """A teacher's command: the next `command_steps` actions are this one (`chooser`:
        "teacher" earns h's bonus, "steer" does not)."""
        index = ACTION_NAMES.index(action)
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
        self.shaping.credit(self.Q, [asked], (self.config.alpha * self._bonus() * weights)[None])
        if self.s is not None and self.s.view == asked.view:
            self.command(action, "steer")
        self.counters["answers"] += 1
        return True

    # -- the values, linear over the state's features ---------------------------------------
    def q(self, s: State) -> np.ndarray:
        """Q(s, .): the mean of the rows of Q of the state's features."""
        return self.Q[s.q].sum(axis=0) / len(s.q)

    def advice(self, s: State) -> np.ndarray:
        """The teacher's bias in s as the policy weighs it now (advice.py)."""
        return self.taught.weighed(s, self.episode)

    def phi(self, s: State) -> float:
        """Phi(s), the potential the teacher's words imply (advice.py)."""
        return self.taught.phi(s)

    # -- states and episodes ------------------------------------------------------------
    def _state_of(self, p: LearnerPercept) -> State:
        s, parent = self.features.encode(p)
        n_q, n_advice, n_place = self.features.sizes
        if n_q > len(self.Q):  # new features: new rows, from what is known, if asked
            known = s.q[s.q < len(self.Q)]
            row = 0.0
            if self.config.init_from_neighbour and parent is not None:
                row = self.Q[parent]  # a new state: its nearest state's values
            elif self.config.init_from_neighbour and len(known):
                row = self.Q[known].sum(axis=0) / len(known)  # the state's other features'
            self.Q = np.vstack([self.Q, np.zeros((n_q - len(self.Q), N_ACTIONS)) + row])
            self.e = np.vstack([self.e, np.zeros((n_q - len(self.e), N_ACTIONS))])
        self.taught.grow(n_advice, n_place)
        return s

    def _end_episode(self) -> None:
        self.interrupt()
        self.episode += 1

    def interrupt(self) -> None:
        """Forgets the episode in progress without counting it (a gap in the observations,
        a replay that stops mid-episode)."""
        self.e[:] = 0.0
        self.s = self.a = None
        self.commands.clear()
        self.G, self.discount, self.held = 0.0, 1.0, 0

"""SARSA(lambda) with dynamic rewards: the paper's Algorithm 1, with eligibility traces.

At every control step, with s the previous state and a the action taken in it:

    observe r, s'                    r = R_RL, the simulator's reward for the step
    (while s' == s, and for its first min_hold steps, the policy's action goes on: r
    accumulates as G = sum gamma^i r_i over the k steps, and the update below uses G and
    gamma^k: SARSA over the states' changes)
    if the teacher selected a:       r <- h(r, a)          (h: + command_reward, bounded)
    select a' from s'                the teacher's command if one is pending, else the
                                     policy derived from Q (epsilon-greedy, or the blend),
                                     never the turn that undoes a policy's turn a
    delta = r + gamma Q(s', a') - Q(s, a)         Q(s', a') = 0 when s' is terminal
    e(s, a) <- 1 (replacing) or e(s, a) + 1 (accumulating)
    Q <- Q + alpha delta e;  e <- gamma lambda e;  s <- s', a <- a'

With goal_prior, Q(s, .) is the sum of two tilings, the state's own values and its goal cell's
(bearing and distance bins alone), each updated with alpha / 2; what is learnt about heading
for the goal then holds in every state of that cell at once.

With the blend, a is a mix of the discrete actions with weights w: Q(s, a) is w . Q(s, .)
and each action's trace grows by its weight, so each is credited in proportion to its share.

"If the user provides feedback f on state s', r <- g(r, f)": spoken feedback arrives late,
so the arbiter credits it to the past steps it was about, with weights, and `credit` adds
g's bounded f to those steps' rewards after the fact: Q <- Q + alpha w f e_k, where e_k are
the traces as they stood at step k (the same change the update would have made had f
arrived in time). Feedback on steps that left the window is counted and dropped.

That is shaping="additive", the paper's. The default, shaping="action_bias" (TAMER+RL's
action biasing), sends g's f and h's bonus to a table H of their own instead of r: the
policy ranks Q + beta H and Q learns from R_RL alone, on the robot's own steps (a replayed
trace, `replay=True`, teaches H alone, unless trace_values). H changes only when the teacher
speaks, so what it taught is not unlearnt as it falls silent (config.py has the measurements).
With advice_generalization the policy's H(s) is the mean of H[s] and the sums of H over the
state's advice tiles (coarser tilings, states.py): tile coding, each tiling credited in full,
so what was said in a state also speaks for the states that share a tile with it.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from protocol import ACTION_NAMES, CreditedFeedback
from services.learner.actions import N_ACTIONS, ActionSet, Decision
from services.learner.config import LearnerConfig
from services.learner.states import Percept, StateSpace


class LearnerPercept(Percept, Protocol):
    reward: float  # R_RL of the step that led here
    outcome: str  # "running" unless the episode ended here
    step: int  # the observation's step id (feedback is credited to these)


@dataclass
class Visit:
    """A decision of the recent past (steps first..last), kept for late feedback."""

    first: int
    last: int
    episode: int
    state: int
    weights: np.ndarray


class Learner:
    def __init__(self, config: LearnerConfig | None = None, seed: int | None = None) -> None:
        self.config = c = config or LearnerConfig()
        self.states = StateSpace(c)
        self.actions = ActionSet(c)
        self.Q = np.zeros((0, N_ACTIONS))  # action values of the states (the fine tiling)
        self.H = np.zeros((0, N_ACTIONS))  # teacher's action bias (shaping="action_bias")
        self.H_tiles = np.zeros((0, N_ACTIONS))  # H summed over each advice tile
        self.e = np.zeros((0, N_ACTIONS))  # eligibility traces
        # The coarse tiling (goal_prior): action values of the goal cells alone, added to Q.
        self.tilings = 2 if c.goal_prior and c.goal_features else 1
        self.Q_goal = np.zeros((self.states.n_cells, N_ACTIONS))
        self.e_goal = np.zeros_like(self.Q_goal)
        self.rng = np.random.default_rng(seed)
        self.episode = 0  # episodes finished
        self.s: int | None = None  # the previous state ...
        self.a: Decision | None = None  # ... and the action taken in it
        self.recent: deque[Visit] = deque(maxlen=c.feedback_window)
        self.commands: deque[int] = deque()  # teacher's actions still to take
        self.counters: Counter[str] = Counter()
        self.td_error = 0.0
        self.G, self.discount, self.held = 0.0, 1.0, 0  # the action in progress
        self.episode_return = 0.0

    # -- Algorithm 1 ----------------------------------------------------------------------
    def step(
        self, p: LearnerPercept, forced: Decision | None = None, replay: bool = False
    ) -> Decision | None:
        """Learns from the step that led to `p` and decides the next action (None when the
        episode ended). `forced` imposes the action; `replay`: the step is a teacher's trace
        replayed, not the robot's own."""
        c = self.config
        learns_q = not replay or c.trace_values or c.shaping == "additive"
        s_next = self._state_of(p)
        ended = p.outcome != "running"
        terminal = ended and p.outcome != "timeout"  # a timeout cuts the episode short: s'
        # still has a future, so the update bootstraps from it (truncation, not termination)
        if self.s is None:  # the first step of an episode
            self.episode_return = 0.0
        else:
            r = p.reward
            if self.a.chooser == "teacher":
                r = self._h(r, self.s, self.a)
            self.G += self.discount * r  # the reward of the action so far, discounted
            self.episode_return += r
            self.discount *= c.gamma
            self.held += 1
            if (
                (s_next == self.s or self.held < c.min_hold)
                and not ended
                and forced is None
                and not self.commands
                and self.a.chooser == "policy"
                and self.held < c.max_hold
            ):
                self.recent[-1].last = p.step  # same state: the action goes on
                return self.a
        a_next = None if terminal else (forced or self._select(s_next))
        if self.s is not None and learns_q:
            q_next = 0.0 if terminal else a_next.weights @ self.value(s_next)
            if ended:
                a_next = None
            delta = self.G + self.discount * q_next - self.a.weights @ self.value(self.s)
            self._mark(self.e, self.s)
            self._mark(self.e_goal, self.states.cells[self.s])
            self.Q += c.alpha / self.tilings * delta * self.e
            self.e *= self.discount * c.lam  # gamma^k lambda after an action held k steps
            if self.tilings == 2:
                self.Q_goal += c.alpha / self.tilings * delta * self.e_goal
                self.e_goal *= self.discount * c.lam
            self.td_error = float(delta)
        self.G, self.discount, self.held = 0.0, 1.0, 0
        if ended:
            self._end_episode()
            return None
        self.recent.append(Visit(p.step, p.step, self.episode, s_next, a_next.weights))
        self.s, self.a = s_next, a_next
        self.counters["decisions"] += 1
        return a_next

    def value(self, s: int) -> np.ndarray:
        """Q(s, .): the state's own values, plus its goal cell's with the goal prior."""
        if self.tilings == 2:
            return self.Q[s] + self.Q_goal[self.states.cells[s]]
        return self.Q[s]

    def _mark(self, e: np.ndarray, row: int) -> None:
        """e(s, a) <- 1 (replacing) or e(s, a) + 1 (accumulating), weighted by the blend."""
        if self.config.traces == "replacing":
            e[row] = np.maximum(e[row], self.a.weights)
        else:
            e[row] += self.a.weights

    def _h(self, r: float, s: int, a: Decision) -> float:
        """h(r, a): the reward of an action the teacher selected (bounded like g)."""
        bonus = float(
            np.clip(
                self.config.command_reward, -self.config.feedback_bound, self.config.feedback_bound
            )
        )
        if self.config.shaping == "action_bias":
            self._advise(s, self.config.alpha * bonus * a.weights)
            return r
        return r + bonus

    def credit(self, step: int, weight: float, f: float) -> bool:
        """Teacher feedback f about the action taken at observation `step`, with the weight
        the arbiter gave it: g(r, f) = r + clip(f), applied after the fact. False (counted)
        if that step is no longer in the window."""
        c = self.config
        f = float(np.clip(f, -c.feedback_bound, c.feedback_bound))
        index = next(
            (
                i
                for i in range(len(self.recent) - 1, -1, -1)
                if self.recent[i].first <= step <= self.recent[i].last
            ),
            None,
        )
        if index is None:
            oldest = self.recent[0].first if self.recent else None
            why = "too_old" if oldest is not None and step < oldest else "unknown_step"
            self.counters[f"feedback_dropped.{why}"] += 1
            return False
        bias = c.shaping == "action_bias"
        credited = self.recent[index]
        trace = 1.0  # e_k(s_j, a_j) = (gamma lambda)^(k - j) along the episode, back from k
        for j in range(index, -1, -1):
            visit = self.recent[j]
            if visit.episode != credited.episode or trace < 1e-4:
                break
            change = c.alpha * weight * f * trace * visit.weights
            if bias:
                self._advise(visit.state, change)
            else:
                self.Q[visit.state] += change / self.tilings
                if self.tilings == 2:
                    self.Q_goal[self.states.cells[visit.state]] += change / self.tilings
            trace *= c.gamma * c.lam
        self.counters["feedback_credited"] += 1
        return True

    def take(self, feedback: CreditedFeedback) -> list[int]:
        """The arbiter's credited feedback: a command, or a reward credited to its steps;
        returns the steps that had left the window (dropped, counted)."""
        if feedback.kind == "command":
            self.command(feedback.command)
            return []
        return [
            c.step for c in feedback.credits if not self.credit(c.step, c.weight, feedback.reward)
        ]

    def command(self, action: str) -> None:
        """A teacher's command: the next `command_steps` actions are this one."""
        index = ACTION_NAMES.index(action)
        self.commands.clear()
        self.commands.extend([index] * self.config.command_steps)
        self.counters["commands"] += 1

    # -- helpers --------------------------------------------------------------------------
    def _select(self, s: int) -> Decision:
        if self.commands:
            return self.actions.one_hot(self.commands.popleft(), "teacher")
        q = self.value(s)
        if self.config.shaping == "action_bias":
            q = q + self.config.bias_weight * self.config.bias_decay**self.episode * self.advice(s)
        barred = None
        if not self.config.turn_back and self.a is not None and self.a.chooser == "policy":
            barred = self.actions.undoing.get(self.a.discrete)
        return self.actions.choose(q, self.config.epsilon(self.episode), self.rng, barred)

    def advice(self, s: int) -> np.ndarray:
        """H(s, .) as the policy weighs it: the state's own, with its tiles' (if any)."""
        tiles = self.states.tiles[s]
        return (self.H[s] + self.H_tiles[tiles].sum(axis=0)) / (1 + len(tiles))

    def _advise(self, s: int, change: np.ndarray) -> None:
        self.H[s] += change
        self.H_tiles[self.states.tiles[s]] += change

    def sum_advice_tiles(self) -> None:
        """H_tiles from H (after H was restored)."""
        self.H_tiles = np.zeros((len(self.states.tile_ids), N_ACTIONS))
        for s, tiles in enumerate(self.states.tiles):
            self.H_tiles[tiles] += self.H[s]

    def _state_of(self, p: Percept) -> int:
        s, parent = self.states.classify(p)
        if s == len(self.Q):  # a new state: a new row, from its nearest neighbour if asked
            row = self.Q[parent] if parent is not None and self.config.init_from_neighbour else 0
            self.Q = np.vstack([self.Q, np.zeros(N_ACTIONS) + row])
            self.H = np.vstack([self.H, np.zeros(N_ACTIONS)])
            new_tiles = len(self.states.tile_ids) - len(self.H_tiles)
            self.H_tiles = np.vstack([self.H_tiles, np.zeros((new_tiles, N_ACTIONS))])
            self.e = np.vstack([self.e, np.zeros(N_ACTIONS)])
        return s

    def _end_episode(self) -> None:
        self.interrupt()
        self.episode += 1

    def interrupt(self) -> None:
        """Forgets the episode in progress without counting it (a gap in the observations,
        a replay that stops mid-episode)."""
        self.e[:] = 0.0
        self.e_goal[:] = 0.0
        self.s = self.a = None
        self.commands.clear()
        self.G, self.discount, self.held = 0.0, 1.0, 0

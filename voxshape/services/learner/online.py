"""The agent of one robot on a live session, without the bus: observations in, actions,
learning summaries and questions out as messages, credited feedback taken exactly once
(`Agent.take`: a copy delivered again after a restart is skipped by id), the episodes a
teacher steered recorded (to be shown to a later learner as its initial traces). `node.py`
puts it on the bus."""

from __future__ import annotations

from collections import Counter

from voxshape.protocol import Action, HelpRequest, LearningSummary, Observation
from voxshape.services.learner.agent import Agent
from voxshape.services.learner.asking import Asker
from voxshape.services.learner.checkpoint import Bookmark
from voxshape.services.learner.sarsa import Learner
from voxshape.services.learner.traces import TraceBook


class OnlineLearner(Agent):
    def __init__(
        self,
        learner: Learner,
        bookmark: Bookmark,
        counters: Counter[str],
        timeout_s: float,
    ) -> None:
        super().__init__(learner, Asker(learner, timeout_s), bookmark, counters)
        self.book = TraceBook()  # episodes a teacher steered, saved as initial traces

    def observe(
        self, obs: Observation
    ) -> tuple[Action | None, LearningSummary, HelpRequest | None]:
        """Learns from the step and decides the next action (None after a terminal step);
        the robot may ask which way."""
        learner = self.learner
        if obs.episode_step == 0 and learner.s is not None:
            learner.interrupt()  # missed the end of the last episode
        decision, question = self.step(obs, obs.episode)
        self.bookmark.step = obs.step
        self.book.record(obs, decision)
        action = None
        if decision is not None:
            action = Action(
                robot=obs.robot,
                episode=obs.episode,
                step=obs.step,
                discrete=decision.discrete,
                v=decision.v,
                omega=decision.omega,
                chooser="policy" if decision.chooser == "policy" else "teacher",
            )
        request = None
        if question is not None:
            self.counters[f"learner.asked.{question.reason}"] += 1
            request = question.request(obs.robot, obs.x, obs.y)
        return action, self.summary(obs), request

    def summary(self, obs: Observation) -> LearningSummary:
        """After a terminal step the robot is in no state: state 0 and no Q-values."""
        learner, s = self.learner, self.learner.s
        return LearningSummary(
            robot=obs.robot,
            episode=obs.episode,
            step=obs.step,
            state=s if s is not None else 0,
            states=len(learner.states),
            q_values=tuple(float(q) for q in learner.q(s)) if s is not None else (),
            td_error=learner.td_error,
            epsilon=learner.config.epsilon(learner.episode),
            reward=obs.reward,
            episode_return=learner.episode_return,
        )

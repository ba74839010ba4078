"""The learner of one robot on a live session, without the bus: observations in, actions,
learning summaries and questions out, credited feedback taken exactly once (a copy delivered
again after a restart is skipped by id), initial traces replayed when due. `node.py` puts it
on the bus."""

from __future__ import annotations

from collections import Counter

from protocol import Action, CreditedFeedback, HelpRequest, LearningSummary, Observation
from services.learner.asking import Asker
from services.learner.checkpoint import Bookmark
from services.learner.sarsa import Learner
from services.learner.traces import TraceBook


class OnlineLearner:
    def __init__(
        self,
        learner: Learner,
        bookmark: Bookmark,
        initial: TraceBook | None,
        counters: Counter[str],
        timeout_s: float,
    ) -> None:
        self.learner, self.bookmark, self.initial = learner, bookmark, initial
        self.counters = counters
        self.asker = Asker(learner, timeout_s)
        self.book = TraceBook()  # episodes a teacher steered, saved as initial traces

    def observe(
        self, obs: Observation
    ) -> tuple[Action | None, LearningSummary, HelpRequest | None]:
        """Learns from the step and decides the next action (None after a terminal step);
        the robot may ask which way."""
        learner = self.learner
        if obs.episode_step == 0 and learner.s is not None:
            learner.interrupt()  # missed the end of the last episode
        decision = learner.step(obs)
        self.bookmark.step = obs.step
        self.book.record(obs, decision)
        if decision is None and self.initial:
            self.initial.replay_if_due(learner)
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
        question = self.asker.after_step(obs, obs.episode)
        request = None
        if question is not None:
            self.counters[f"learner.asked.{question.reason}"] += 1
            request = question.request(obs.robot, obs.x, obs.y)
        return action, self.summary(obs), request

    def take(self, feedback: CreditedFeedback) -> list[int]:
        """Takes feedback once; returns the steps it credits that had left the window."""
        if not self.bookmark.take(feedback.id):
            self.counters["learner.feedback_taken_before"] += 1
            return []
        dropped = self.asker.take(feedback)
        if dropped:
            self.counters["learner.feedback_partly_dropped"] += 1
        return dropped

    def summary(self, obs: Observation) -> LearningSummary:
        """After a terminal step the robot is in no state: state 0 and no Q-values."""
        learner, s = self.learner, self.learner.s
        return LearningSummary(
            robot=obs.robot,
            episode=obs.episode,
            step=obs.step,
            state=int(s.q[0]) if s is not None else 0,
            states=len(learner.features),
            q_values=tuple(float(q) for q in learner.q(s)) if s is not None else (),
            td_error=learner.td_error,
            epsilon=learner.config.epsilon(learner.episode),
            reward=obs.reward,
            episode_return=learner.episode_return,
        )

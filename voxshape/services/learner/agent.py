"""One robot's agent online: its learner, and beside it the policy that asks "which way?".
The learner service (online.py, node.py) and the in-process experiments
(experiment/inprocess.py) both step it and give it every credited word through `take`, the
one way a word reaches the learner:

    taken before (its id)        skipped, counted: a kept output delivers it again after a
                                 restart, and the checkpoint holds its effect
    a command answering a        Learner.answer: advised in the state asked in, steering the
    question (its id)            robot if it is still there; the asker closes the question
    another command              Learner.command: the next actions, and h's bonus
    a reward                     Learner.credit for each credited step, by its weight
"""

from __future__ import annotations

from collections import Counter

from voxshape.protocol import CreditedFeedback
from voxshape.services.learner.actions import Decision
from voxshape.services.learner.asking import Asker, Question
from voxshape.services.learner.checkpoint import Bookmark
from voxshape.services.learner.sarsa import Learner, LearnerPercept


class Agent:
    def __init__(
        self,
        learner: Learner,
        asker: Asker | None = None,
        bookmark: Bookmark | None = None,
        counters: Counter[str] | None = None,
    ) -> None:
        self.learner, self.asker = learner, asker
        self.bookmark = bookmark if bookmark is not None else Bookmark()
        self.counters = counters if counters is not None else Counter()

    def step(
        self, percept: LearnerPercept, episode: int
    ) -> tuple[Decision | None, Question | None]:
        """The learner learns from the step and decides the next action (None after a
        terminal step); then the robot may ask which way."""
        decision = self.learner.step(percept)
        asker = self.asker
        return decision, asker.after_step(percept, episode) if asker is not None else None

    def take(self, feedback: CreditedFeedback) -> list[int]:
        """A credited word, once (the module's docstring); returns the steps it credits that
        had left the learner's window (dropped, counted)."""
        if not self.bookmark.first_time(feedback.id):
            self.counters["learner.feedback_taken_before"] += 1
            return []
        learner = self.learner
        if feedback.kind == "command" and feedback.question is not None:
            if self.asker is not None:
                self.asker.answered(feedback.question)
            step = feedback.credits[0].step
            dropped = [] if learner.answer(step, feedback.command) else [step]
        elif feedback.kind == "command":
            learner.command(
                feedback.command, credits=[(c.step, c.weight) for c in feedback.credits]
            )
            dropped = []
        else:
            dropped = [
                c.step
                for c in feedback.credits
                if not learner.credit(c.step, c.weight, feedback.reward)
            ]
        if dropped:
            self.counters["learner.feedback_partly_dropped"] += 1
        return dropped

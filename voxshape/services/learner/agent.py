"""One robot's agent online: its learner, and beside it the policy that asks "which way?".
The learner service (online.py, node.py) and the in-process experiments
(experiment/inprocess.py) both step it and give it every credited word through `take`, the
one way a word reaches the learner:

    taken before (its id)        skipped, counted: a kept output delivers it again after a
                                 restart, and the checkpoint holds its effect
    a command answering a        a vote about the way from where the question was asked
    question (its id)            (words.py), and the robot steered by it if it is still
                                 in the state it asked in; the asker closes the question
    another command              the robot steered by it (Learner.command), and a vote about
                                 the way from the poses the person saw (words.py)
    a judgement                  a vote about the motion judged at each credited step, by its
                                 weight (words.py)
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
        learner, words = self.learner, self.learner.words
        if feedback.kind == "command" and feedback.question is not None:
            asked_in = self.asker.answered(feedback.question) if self.asker else None
            step = feedback.credits[0].step
            dropped = [] if words.answered(step, feedback.command) else [step]
            if asked_in is not None and asked_in == learner.s:  # still where it asked
                learner.command(feedback.command)
        elif feedback.kind == "command":
            seen = [(c.step, c.weight) for c in feedback.credits]
            looked = words.pose_at(max(seen, key=lambda credit: credit[1])[0])
            learner.command(feedback.command, None if looked is None else looked[2])
            dropped = words.commanded(feedback.command, seen)
        else:
            dropped = [
                c.step
                for c in feedback.credits
                if not words.judged(c.step, c.weight, feedback.reward)
            ]
        if dropped:
            self.counters["learner.feedback_partly_dropped"] += 1
        return dropped

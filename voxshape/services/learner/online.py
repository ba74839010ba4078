"""One robot's agent on a live session, in messages and without the bus: an observation in;
the next action, a learning summary and perhaps a question out; the episodes a teacher
steered recorded (to be shown to a later learner as its initial traces). Credited feedback
goes straight to the agent (`Agent.take`, which skips a copy delivered again after a
restart). `node.py` puts it on the bus."""

from __future__ import annotations

from collections import Counter

from voxshape.protocol import Action, HelpRequest, LearningSummary, Observation
from voxshape.services.learner.agent import Agent
from voxshape.services.learner.asking import Asker
from voxshape.services.learner.checkpoint import Bookmark
from voxshape.services.learner.sarsa import Learner
from voxshape.services.learner.traces import TraceBook


def online_agent(
    learner: Learner, bookmark: Bookmark, counters: Counter[str], timeout_s: float
) -> Agent:
    """A robot's agent on a live session: its learner, and the asker that may ask which way
    (an episode lasting `timeout_s` robot seconds at most)."""
    return Agent(learner, Asker(learner, timeout_s), bookmark, counters)


def observe(
    agent: Agent, book: TraceBook, obs: Observation
) -> tuple[Action | None, LearningSummary, HelpRequest | None]:
    """The agent learns from the step and decides the next action (None after a terminal
    step), recorded in `book`; the robot may ask which way."""
    learner = agent.learner
    if obs.episode_step == 0 and learner.s is not None:
        learner.interrupt()  # missed the end of the last episode
    decision, question = agent.step(obs, obs.episode)
    agent.bookmark.step = obs.step
    book.record(obs, decision)
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
        agent.counters[f"learner.asked.{question.reason}"] += 1
        request = question.request(obs.robot, obs.x, obs.y)
    return action, learning_summary(learner, obs), request


def learning_summary(learner: Learner, obs: Observation) -> LearningSummary:
    """What the learner makes of the step; after a terminal step the robot is in no state:
    state 0 and no Q-values."""
    s = learner.s
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

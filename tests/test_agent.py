"""The agent core (voxshape/services/learner/agent.py): every credited word reaches the learner
through `Agent.take`, once; the robot asks "which way?" beside it, and an answer is matched by the
question's id, within the protocol's one question lifetime."""

from __future__ import annotations

import ast
from collections import Counter
from dataclasses import dataclass, replace
from pathlib import Path

import pytest

from tests.learner_support import EXACT, FORWARD, LEFT, WALL_LEFT, WALL_RIGHT, P
from voxshape.protocol import QUESTION_OPEN_S, Credit, CreditedFeedback
from voxshape.services.learner import checkpoint
from voxshape.services.learner.agent import Agent
from voxshape.services.learner.asking import Asker
from voxshape.services.learner.online import OnlineLearner
from voxshape.services.learner.sarsa import Learner
from voxshape.world.robot import CONTROL_PERIOD_S

LEARNER_PACKAGE = Path(__file__).parent.parent / "voxshape" / "services" / "learner"


@dataclass(frozen=True)
class Seen(P):
    """A percept with the robot's episode clock and bumps, as the Asker reads it."""

    episode_step: int = 0
    collided: bool = False


def asking_agent(**ask: float) -> Agent:
    config = replace(EXACT, min_hold=1)
    learner = Learner(replace(config, ask=replace(config.ask, **ask)), seed=0)
    return Agent(learner, Asker(learner, timeout_s=300.0))


def command(step: int, action: str = "left", question: str | None = None) -> CreditedFeedback:
    return CreditedFeedback(
        robot="r1", kind="command", reward=None, command=action,
        credits=(Credit(step=step, weight=1.0),), sources=(f"u{step}",), teachers=("ana",),
        question=question,
    )  # fmt: skip


def test_a_word_reaches_the_learner_by_one_function():
    """`take` is defined once in the learner's package, and only the agent calls the
    learner's ways of taking a word (the service and the experiments call the agent)."""
    defined, callers = [], set()
    for path in sorted(LEARNER_PACKAGE.parent.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text("utf-8"))):
            is_take = isinstance(node, ast.FunctionDef) and node.name == "take"
            if is_take and path.parent == LEARNER_PACKAGE:
                defined.append(path.name)
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
                receiver = ast.unparse(node.func.value)
                ways_in = ("judged", "commanded", "answered", "command")
                if node.func.attr in ways_in and ("learner" in receiver or "words" in receiver):
                    callers.add(path.relative_to(LEARNER_PACKAGE.parent).as_posix())
    assert defined == ["agent.py"]
    assert callers == {"learner/agent.py"}


def test_credited_feedback_is_taken_whole_and_names_the_steps_it_dropped():
    agent = Agent(Learner(replace(EXACT, feedback_window_s=0.3), seed=0))  # 3 steps kept
    learner = agent.learner
    for step in range(6):
        learner.step(P(WALL_LEFT, reward=0.0, step=step), forced=learner.actions.one_hot(FORWARD))
    credits = (Credit(step=1, weight=0.5), Credit(step=5, weight=0.5))
    reward = CreditedFeedback(
        robot="r1", kind="reward", reward=10.0, command=None, credits=credits,
        sources=("u1",), teachers=("ana",),
    )  # fmt: skip
    assert agent.take(reward) == [1]  # step 1 left the window; step 5 is credited
    assert learner.counters["feedback_credited"] == 1
    assert agent.counters["learner.feedback_partly_dropped"] == 1
    # a turn said about a heading the person saw: turned until command_aim aside of it, for
    # at most twice command_steps
    assert agent.take(command(5)) == [] and learner.aim is not None
    assert list(learner.commands) == [LEFT] * (2 * EXACT.command_steps)


def test_online_feedback_is_taken_once_even_when_delivered_again():
    online = OnlineLearner(Learner(EXACT, seed=0), checkpoint.Bookmark(), Counter(), 300.0)
    online.learner.step(P(WALL_LEFT, step=0))
    feedback = CreditedFeedback(
        robot="r1", kind="reward", reward=10.0, command=None,
        credits=(Credit(step=0, weight=1.0),), sources=("u1",), teachers=("ana",),
    )  # fmt: skip
    assert online.take(feedback) == [] and online.take(feedback) == []
    assert online.learner.counters["feedback_credited"] == 1
    assert online.counters["learner.feedback_taken_before"] == 1


def test_a_stuck_robot_asks_once_within_its_budget_and_learns_from_the_answer():
    agent = asking_agent()
    learner, asked = agent.learner, []
    for k in range(1500):  # 2.5 robot minutes in one place: nothing gets better
        _, question = agent.step(Seen(WALL_LEFT, step=k, episode_step=k), episode=0)
        if question is not None:
            asked.append(question)
            if len(asked) == 1:  # answered at once: "left"
                assert agent.take(command(question.step, question=question.id)) == []
                assert learner.way.spoken_at((0.0, 0.0))  # a vote where it asked
                assert learner.commands[0] == LEFT  # and steered: it is still there
    first = asked[0]
    assert first.reason in ("unsure", "stuck") and first.step < 20
    assert first.request("r1", 0.0, 0.0).id == first.id  # the answer names it
    # 0.5 a robot minute: one at once, the next 2 robot minutes later
    assert len(asked) == 2 and asked[1].step >= first.step + 1200
    assert agent.asker.reasons.total() == 2


def test_an_answer_is_matched_by_the_questions_id_not_its_step():
    agent = asking_agent()
    learner = agent.learner
    _, question = agent.step(Seen(WALL_LEFT, step=0), episode=0)
    assert question is not None
    # a command credited to the question's step that answers nothing is a command
    agent.take(command(question.step))
    assert learner.counters["commands"] == 1 and learner.counters["answers"] == 0
    assert agent.asker.open is not None
    agent.take(command(question.step, question="another question"))  # some other question's
    assert agent.asker.open is not None and learner.counters["answers"] == 1
    agent.take(command(question.step, question=question.id))
    assert agent.asker.open is None and learner.counters["answers"] == 2


def test_an_answer_frees_the_view_it_was_asked_in_not_the_robots_view_now():
    agent = asking_agent()
    learner = agent.learner
    _, question = agent.step(Seen(WALL_LEFT, step=0), episode=0)
    assert question is not None
    asked_in = learner.s
    agent.step(Seen(WALL_RIGHT, step=1, episode_step=1), episode=0)  # moved on before the answer
    assert learner.s != asked_in
    assert agent.take(command(question.step, question=question.id)) == []
    assert asked_in not in agent.asker._asked_views  # it may ask there again
    assert learner.commands == type(learner.commands)()  # not steered: it is elsewhere now


def test_an_unanswered_question_is_open_for_the_protocols_lifetime():
    """The robot asks again (with the budget for it) only once QUESTION_OPEN_S, the time the
    arbiter waits for an answer, has passed: one lifetime on both sides."""
    agent = asking_agent(per_robot_minute=600.0)
    asked = []
    for k in range(200):  # asked in one place, then bumping in another: stuck there
        wall = WALL_LEFT if k == 0 else WALL_RIGHT
        _, question = agent.step(Seen(wall, step=k, episode_step=k, collided=k > 0), episode=0)
        if question is not None:
            asked.append(question.step)
    assert asked[0] == 0
    assert (asked[1] - 1) * CONTROL_PERIOD_S <= QUESTION_OPEN_S < asked[1] * CONTROL_PERIOD_S


def test_an_asker_that_reached_the_goal_asks_again_where_it_asked_before():
    """After the first goal, each episode starts afresh: the views asked in, the bumps and
    the best value of the last episode are forgotten (they were kept for good)."""
    agent = asking_agent()
    asked, step = [], 0
    for episode, length in ((0, 100), (1, 2000)):
        for k in range(length):
            ends = episode == 0 and k == length - 1
            p = Seen(WALL_LEFT, step=step, episode_step=k, outcome="goal" if ends else "running")
            if (question := agent.step(p, episode=episode)[1]) is not None:
                asked.append(question)
            step += 1
    assert [q.episode for q in asked][:1] == [0]  # asked in the first episode, in this view
    # ... and in the second (beyond twice its fastest, 10 s), in the same view again
    assert any(q.episode == 1 for q in asked), asked


def test_only_a_command_answers_a_question():
    with pytest.raises(Exception, match="only a command answers a question"):
        CreditedFeedback(
            robot="r1", kind="reward", reward=1.0, command=None,
            credits=(Credit(step=0, weight=1.0),), sources=("u",), teachers=("ana",),
            question="q1",
        ).check()  # fmt: skip

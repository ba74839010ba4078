"""The demo's closing lines: in a sentence or two, what the robot learnt and how long it took
(episodes, robot and wall minutes), then the words said to it and how many were understood.

Each sentence is one function of the run's `Ending`, in CLOSING's order; one that has nothing
to say returns None. A sentence about what the words bought (the run set against one learnt
alone) is one more such function, appended to CLOSING. demo.md keeps the same lines.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

from voxshape.protocol import Said, TeachingStats

How = Literal["learnt", "gave up", "interrupted", "ended by its person", "failed"]


def plural(n: int, word: str) -> str:
    """`1 word`, `2 words`."""
    return f"{n} {word}{'' if n == 1 else 's'}"


@dataclass
class WordCount:
    """The words said to the robot (the simulated teacher says what it speaks, a Said), those
    the arbiter had (heard: recognized, or typed) and understood, per teacher, as its
    TeachingStats count them for the robot."""

    said: int = 0
    heard: dict[str, int] = field(default_factory=dict)
    understood: dict[str, int] = field(default_factory=dict)

    def on_said(self, said: Said) -> None:
        self.said += 1

    def on_teaching(self, stats: TeachingStats) -> None:
        for t in stats.teachers:
            self.heard[t.teacher] = max(self.heard.get(t.teacher, 0), t.utterances)
            self.understood[t.teacher] = max(self.understood.get(t.teacher, 0), t.understood)


@dataclass(frozen=True)
class Ending:
    """How a demo ended: `episodes` and `robot_minutes` up to the episode it learnt in (all
    of them when it did not), `wall_minutes` from the session being up to that episode's
    end (or to the end), `more` the episodes after it (a web demo goes on)."""

    task: str  # "task 1", "map office.toml (Office)"
    how: How
    learnt: bool
    episodes: int
    robot_minutes: float
    wall_minutes: float
    words: WordCount
    more: int = 0
    goals: int = 0  # episodes that reached the goal (said when it gave up)
    alone: Alone | None = None  # the same room and seed learnt without a person


@dataclass(frozen=True)
class Alone:
    """The same room and seed learnt in one process without anybody speaking."""

    learnt: bool
    episodes: int
    robot_minutes: float
    wall_seconds: float


def learnt_sentence(e: Ending) -> str:
    """Whether the robot learnt its task, in how many episodes and minutes; nothing said
    of convergence when it did not."""
    wall = (
        f"{e.wall_minutes:.1f} wall minutes"
        if e.wall_minutes >= 1
        else plural(round(e.wall_minutes * 60), "wall second")
    )
    took = f"{e.robot_minutes:.1f} robot minutes, {wall}"
    if e.learnt:
        then = f" It went on for {plural(e.more, 'more episode')}." if e.more else ""
        return f"The robot learnt {e.task} in {plural(e.episodes, 'episode')} ({took}).{then}"
    if e.how == "gave up":
        return (
            f"The robot had not learnt {e.task} after {plural(e.episodes, 'episode')} ({took}; "
            f"{e.goals} reached the goal): --max-episodes gives it more, another --seed "
            "another chance."
        )
    stopped = "You stopped it" if e.how == "ended by its person" else "Stopped"
    return f"{stopped} after {plural(e.episodes, 'episode')} ({took}), before it learnt {e.task}."


def words_sentence(e: Ending) -> str:
    """How many words were said to it, heard and understood."""
    heard, understood = sum(e.words.heard.values()), sum(e.words.understood.values())
    said = max(e.words.said, heard)  # a person's typed words have no Said
    if not said:
        return "No word was said to it."
    if said == heard:
        return f"{plural(heard, 'word')} reached it, {understood} understood."
    return f"{plural(said, 'word')} said to it: {heard} heard, {understood} understood."


def bought_sentence(e: Ending) -> str | None:
    """What the words bought, or cost: the taught run against the same room and seed learnt
    alone (in one process)."""
    a = e.alone
    if a is None or not e.learnt:
        return None
    if not a.learnt:
        return (
            f"Alone, the same robot had not learnt it after {plural(a.episodes, 'episode')} "
            f"({a.robot_minutes:.1f} robot minutes): the words made the difference."
        )
    saved = a.robot_minutes - e.robot_minutes
    verdict = "saved" if saved >= 0 else "cost"
    return (
        f"Alone (the same room and seed, nobody speaking, {a.wall_seconds:.0f} wall seconds "
        f"in one process) it learnt it in {plural(a.episodes, 'episode')} and "
        f"{a.robot_minutes:.1f} robot minutes: the words {verdict} "
        f"{abs(saved):.1f} robot minutes."
    )


CLOSING: tuple[Callable[[Ending], str | None], ...] = (
    learnt_sentence,
    words_sentence,
    bought_sentence,
)


def closing_lines(ending: Ending) -> list[str]:
    """The demo's closing sentences, in CLOSING's order."""
    return [line for sentence in CLOSING if (line := sentence(ending))]

"""The demo's watch of its robot: each ended episode shown once the arbiter's count of its
interventions is final, to convergence or the episode bound (pure: messages in, lines out),
and whether the robot still makes progress."""

from __future__ import annotations

from dataclasses import dataclass, field

from voxshape.lab.closing import Ending, WordCount
from voxshape.lab.report.summary import STEP_SECONDS
from voxshape.protocol import EpisodeEvent, Learnt, TeachingStats
from voxshape.services.learner.convergence import Convergence, EpisodeResult

FINAL_WAIT_S = 6.0  # after an episode ends, its final interventions come within the arbiter's
# settle time (3 s); an episode is shown without them after this


@dataclass
class ShownEpisode:
    """An ended episode as displayed."""

    number: int
    outcome: str
    steps: int
    seconds: float
    ended_at: float  # monotonic
    interventions: int | None = None  # None until final (or given up waiting)


@dataclass
class StallWatch:
    """Whether the robot makes progress: its steps advancing (pure: steps in, verdicts out).
    An episode may last minutes at real time; a robot whose steps stop is stuck."""

    timeout: float  # seconds without a new step
    since: float  # monotonic: when the last new step (or the start) was seen
    step: int = -1

    def on_step(self, step: int, now: float) -> bool:
        """True if this step is progress after a stall."""
        stalled = self.stalled(now)
        if step != self.step:
            self.step, self.since = step, now
            return stalled
        return False

    def stalled(self, now: float) -> bool:
        return now - self.since > self.timeout


@dataclass
class ConvergenceWatch:
    """Episodes of one robot and the arbiter's interventions per episode, to convergence
    (pure: messages in, lines out), judged by `convergence` (the map run, the learner's
    settings: `watch_of`)."""

    robot: str
    max_episodes: int
    convergence: Convergence
    episodes: list[ShownEpisode] = field(default_factory=list)
    interventions: dict[int, tuple[int, bool]] = field(default_factory=dict)  # (count, final)
    title: str = "its task"  # what it learns: "task 1", "map office.toml (Office)"
    lasting: bool = False  # episodes go on after convergence (a web demo, until its person)
    started: float = 0.0  # monotonic: when the session was up
    learnt_at: float | None = None  # monotonic: when the episode it converged in ended
    _shown: int = 0

    def on_episode(self, event: EpisodeEvent, now: float) -> None:
        if event.robot != self.robot or event.kind == "start" or self.done:
            return
        seconds = event.episode_steps * STEP_SECONDS
        self.episodes.append(
            ShownEpisode(event.episode, event.kind, event.episode_steps, seconds, now)
        )
        if not self.convergence.converged:
            self.convergence.add(EpisodeResult(event.kind, event.episode_steps, seconds))
            self.learnt_at = now if self.convergence.converged else None

    def on_teaching(self, stats: TeachingStats) -> None:
        if stats.robot == self.robot:
            self.interventions[stats.episode] = (stats.interventions, stats.final)

    @property
    def done(self) -> bool:
        """Converged, or at the episode bound; never for a lasting demo (its person ends it)."""
        if self.lasting:
            return False
        return self.convergence.converged or len(self.episodes) >= self.max_episodes

    def due_lines(self, now: float, flush: bool = False, mark: bool = True) -> list[str]:
        """Lines of the ended episodes whose interventions are final (or waited for enough);
        `mark`: the one it converged in says so (not after an interrupt)."""
        lines = []
        while self._shown < len(self.episodes):
            e = self.episodes[self._shown]
            count, final = self.interventions.get(e.number, (0, False))
            if not (final or flush or now - e.ended_at >= FINAL_WAIT_S):
                break
            e.interventions = count
            lines.append(self.line(e, mark))
            self._shown += 1
        return lines

    def line(self, e: ShownEpisode, mark: bool = True) -> str:
        c = self.convergence
        converged = mark and c.converged and e.number == self.episodes[c.n_episodes - 1].number
        return (
            f"episode {e.number:>3}  {e.outcome:<9} {e.steps:>5} steps "
            f"({e.seconds:6.1f} s of robot time)  interventions {e.interventions:>3}"
            + ("  <- converged" if converged else "")
        )

    def learnt(self) -> Learnt | None:
        """What the pages are told once the robot has learnt (None before)."""
        c = self.convergence
        if not c.converged:
            return None
        number = self.episodes[c.n_episodes - 1].number
        return Learnt(
            robot=self.robot,
            episode=number,
            episodes=c.n_episodes,
            robot_seconds=c.learning_time,
            task=self.title,
        )

    def ending(self, code: int, words: WordCount, now: float) -> Ending:
        """How the demo ended, from its training's exit code (0: done, 1: an error, 130:
        interrupted, which ends a lasting demo as its person meant)."""
        c = self.convergence
        how = {1: "failed", 130: "ended by its person" if self.lasting else "interrupted"}.get(
            code, "learnt" if c.converged else "gave up"
        )
        until = self.learnt_at if self.learnt_at is not None else now
        return Ending(
            task=self.title,
            how=how,  # type: ignore[arg-type]
            learnt=c.converged,
            episodes=c.n_episodes,
            robot_minutes=c.learning_time / 60,
            wall_minutes=(until - self.started) / 60,
            words=words,
            more=len(self.episodes) - c.n_episodes if c.converged else 0,
            goals=sum(e.outcome == "goal" for e in self.episodes),
        )

    @property
    def all_shown(self) -> bool:
        return self._shown >= len(self.episodes)

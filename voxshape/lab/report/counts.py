"""Episodes and interventions counted one way for every file of a run (summary.md, the
demo's demo.md): to convergence, judged by the map the session ran on, and in all; the
interventions are the arbiter's own count (TeachingStats), as in the paper's Table 3."""

from __future__ import annotations

from dataclasses import dataclass

from voxshape.lab.closing import plural
from voxshape.lab.report.summary import RobotSummary
from voxshape.services.learner.config import LearnerConfig
from voxshape.services.learner.convergence import Convergence, EpisodeResult, convergence_on
from voxshape.world.maps import Map

INTERVENTIONS_ARE = (
    "interventions are the utterances the arbiter understood about an episode, its own count "
    "(TeachingStats), as in the paper's Table 3"
)


@dataclass(frozen=True)
class EpisodeCounts:
    """A robot's episodes and interventions as every file of a run states them (summary.md,
    the demo's demo.md): to convergence, and all that the log holds."""

    convergence: Convergence  # over the ended episodes, in the order they happened
    converged_at: str | None  # the label of the episode that converged
    ended: int  # episodes ended in the log
    interventions: int  # about the ended episodes
    unfinished: int  # episodes still running when the log ends (or cut by a restart)
    unfinished_interventions: int  # about those
    provisional: int  # ended episodes whose count is not the arbiter's final one

    def describe(self) -> str:
        """The counts in two sentences: to convergence, then all that was recorded."""
        c = self.convergence
        if c.converged:
            head = (
                f"The robot converged after {c.n_episodes} episodes ({c.learning_time / 60:.1f} "
                f"robot minutes, at episode {self.converged_at}). To convergence: "
                f"{plural(c.n_episodes, 'episode')}, {plural(c.interventions, 'intervention')}"
            )
        else:
            head = f"The robot did not converge within the {self.ended} episodes recorded"
        tail = (
            f"recorded in all: {plural(self.ended, 'episode')} ended, "
            f"{plural(self.interventions, 'intervention')}"
        )
        if self.unfinished:
            tail += (
                f", and {plural(self.unfinished, 'unfinished episode')} "
                f"({plural(self.unfinished_interventions, 'intervention')} so far)"
            )
        text = f"{head}; {tail}."
        if self.provisional:
            lack = "lacks" if self.provisional == 1 else "lack"
            text += (
                f" {self.provisional} of the ended episodes {lack} the arbiter's final count: "
                "the session stopped before it settled."
            )
        return text


def count_episodes(robot: RobotSummary, m: Map, config: LearnerConfig) -> EpisodeCounts:
    """Episodes and interventions to convergence (judged by map `m`'s shortest time and the
    run's learner `config`, the learner's rule) and in all; the one count every file of a
    run states."""
    convergence = convergence_on(m, config)
    ended = robot.ended
    for e in ended:
        convergence.add(EpisodeResult(e.outcome, e.steps, e.seconds, e.interventions))
    running = [e for e in robot.episodes if e.outcome == "running"]
    at = convergence.converged_at
    return EpisodeCounts(
        convergence=convergence,
        converged_at=None if at is None else robot.label(ended[at]),
        ended=len(ended),
        interventions=sum(e.interventions for e in ended),
        unfinished=len(running),
        unfinished_interventions=sum(e.interventions for e in running),
        provisional=sum(not e.final for e in ended),
    )

"""`voxshape report RUN_DIR`: pictures and a short summary of a session, without a viewer.

Reads the event log (the session's one record) and writes into RUN_DIR/report/:

    trajectories-<robot>.png   the map, y-up, with the paths of a few episodes
    learning-<robot>.png       episode returns (and their moving average), steps, interventions
    rewards-<robot>.png        return within each episode over the steps; the teacher's words
                               at their value; the reward credited to each step; when
                               utterances, feedback and commands arrived
    summary.md                 the numbers, and the pictures

Episodes and interventions are counted one way for every file of a run (`count_episodes`, which
the demo's demo.md uses too): interventions are the utterances the arbiter understood about an
episode, its own count (TeachingStats, as in the paper's Table 3), and convergence is judged by
the map the session ran on. A simulator that restarted within one log (its episode numbers and
steps start again at 0) starts a new run: episodes are kept in the order they happened, never
merged by number.

Its parts: summary.py (the log summed up per robot, pure), counts.py (episodes and
interventions, the one count), pictures.py (matplotlib, headless), summary_md.py (summary.md)
and command.py (the command, which this package exports).
"""

from voxshape.lab.report.command import LoadedRun, add_arguments, load_run, run, write_report

__all__ = ["LoadedRun", "add_arguments", "load_run", "run", "write_report"]

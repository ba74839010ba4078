"""The paper's own figures: its four built-in tasks, Tables 2 and 3 as printed, its averages,
and `paper_average`, its averages over any of those tasks (what our figures stand beside)."""

from __future__ import annotations

import statistics
from collections.abc import Iterable

TASKS = ("1", "2", "3", "4")


# The paper's Tables 2 and 3 (3 repeats per cell). Times in minutes.
PAPER_EPISODES = {
    "rl": {"1": 13, "2": 6, "3": 12, "4": 7},
    "rl+f": {"1": 9, "2": 7, "3": 12, "4": 12},
    "rl+t+f": {"1": 6, "2": 7, "3": 7, "4": 11},
}
PAPER_MINUTES = {
    "rl": {"1": 103.93, "2": 66.4, "3": 100.65, "4": 99.1},
    "rl+f": {"1": 19.59, "2": 15.1, "3": 38.2, "4": 23.43},
    "rl+t+f": {"1": 12.85, "2": 13, "3": 18.09, "4": 24.61},
    "rl+t+f-perfect": {"2": 7.6},
}
PAPER_INTERVENTIONS = {
    "rl+f": {"1": 71, "2": 53, "3": 143, "4": 69},
    "rl+t+f": {"1": 23, "2": 34, "3": 40, "4": 72},
    "rl+t+f-perfect": {"2": 39},
}
# The paper's averages over its four tasks, as printed; over fewer tasks, paper_average computes
# them from the per-task tables above.
PAPER_AVERAGE = {
    "episodes": {"rl": 9.5, "rl+f": 10, "rl+t+f": 7.75},
    "minutes": {"rl": 92.54, "rl+f": 24.08, "rl+t+f": 17.13},
    "interventions": {"rl+f": 84, "rl+t+f": 42},
    "speedup": {"rl+f": 3.84, "rl+t+f": 5.4},
}


def paper_average(tasks: Iterable[str]) -> dict[str, dict[str, float]]:
    """The paper's averages over `tasks` (map files have none and are left out), from its
    per-task tables: episodes, minutes and interventions per setting, and each setting's
    speedup (the paper's mean RL minutes over those tasks / the setting's). A setting without
    a figure for every one of the tasks has none; over all four tasks, the printed averages."""
    built_in = [t for t in TASKS if t in set(tasks)]
    if built_in == list(TASKS):
        return {key: dict(values) for key, values in PAPER_AVERAGE.items()}
    if not built_in:
        return {key: {} for key in PAPER_AVERAGE}

    def mean(table: dict[str, dict[str, float]]) -> dict[str, float]:
        return {
            setting: statistics.fmean(figures[t] for t in built_in)
            for setting, figures in table.items()
            if all(t in figures for t in built_in)
        }

    minutes = mean(PAPER_MINUTES)
    speedup = {s: minutes["rl"] / m for s, m in minutes.items() if s != "rl" and "rl" in minutes}
    return {
        "episodes": mean(PAPER_EPISODES),
        "minutes": minutes,
        "interventions": mean(PAPER_INTERVENTIONS),
        "speedup": speedup,
    }

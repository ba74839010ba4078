"""figure2.png: episode duration against episode, one line per setting (the paper's
Figure 2)."""

from __future__ import annotations

import statistics
from pathlib import Path

from voxshape.lab.experiment.inprocess import SETTINGS, RunResult
from voxshape.lab.experiment.legend import SETTING_STYLES


def figure2(results: list[RunResult], path: Path) -> None:
    """Episode duration (minutes) against episode, one line per setting, averaged over the
    runs (all tasks and seeds) that are still learning at that episode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for setting in SETTINGS:
        runs = [r.durations_s[: r.episodes] for r in results if r.setting == setting]
        if not runs:
            continue
        # Up to the last episode that a quarter of the runs (3 at least) still learn: beyond,
        # a line is the noise of a few slow runs.
        enough = min(len(runs), max(3, len(runs) // 4))
        longest = max(i for i in range(1, max(len(d) for d in runs) + 1)
                      if sum(len(d) >= i for d in runs) >= enough)  # fmt: skip
        mean = [statistics.fmean(d[i] for d in runs if len(d) > i) / 60 for i in range(longest)]
        style = SETTING_STYLES[setting]
        ax.plot(range(1, longest + 1), mean, marker=style.marker, markersize=3, label=style.label)
    ax.set_xlabel("episode")
    ax.set_ylabel("episode duration (robot minutes)")
    ax.set_title("Average episode duration over the tasks (cf. the paper's Figure 2)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)

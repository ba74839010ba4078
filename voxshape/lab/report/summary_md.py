"""summary.md: a session's numbers per robot, and its pictures."""

from __future__ import annotations

import statistics
from pathlib import Path

from voxshape.lab.report.counts import INTERVENTIONS_ARE, EpisodeCounts
from voxshape.lab.report.summary import MOVING_AVERAGE, SessionSummary
from voxshape.world.maps import Map


def summary_markdown(
    summary: SessionSummary,
    m: Map,
    pictures: dict[str, list[Path]],
    counts: dict[str, EpisodeCounts],
) -> str:
    """summary.md: the session's traffic, then per robot its counts (count_episodes), a table
    of its numbers and its pictures."""
    lines = [f"# Session {summary.session}", ""]
    duration = (summary.last_wall or 0) - (summary.first_wall or 0)
    lines += [
        f"- map: {m.name}",
        f"- {summary.records} messages over {duration:.1f} s of wall time; "
        f"{summary.rejected} rejected, {summary.unknown_types} of unknown types{_gaps(summary)}",
        f"- nodes seen: {', '.join(sorted(summary.nodes)) or 'none'}",
        "",
    ]
    for name, r in sorted(summary.robots.items()):
        ended = r.ended
        outcomes = {k: sum(e.outcome == k for e in ended) for k in ("goal", "collision", "timeout")}
        last = ended[-MOVING_AVERAGE:]
        best = max(ended, key=lambda e: e.env_return) if ended else None
        count = counts[name]
        lines += [f"## Robot {name}", ""]
        if r.restarts:
            lines += [
                f"The simulator started {r.runs} times in this log (its episode numbers start "
                "again at 0): episodes are named run:number and kept in the order they "
                f"happened ({r.span()}).",
                "",
            ]
        lines += [
            count.describe(),
            "",
            f"Convergence: {count.convergence.rule()}; {INTERVENTIONS_ARE}.",
            "",
            "| | |",
            "|---|---|",
            f"| steps observed | {len(r.steps)} |",
            f"| episodes ended | {len(ended)}: {outcomes['goal']} goal, "
            f"{outcomes['collision']} collision, {outcomes['timeout']} timeout |",
            f"| mean return, last {len(last)} | "
            f"{statistics.fmean(e.env_return for e in last):+.1f} |"
            if last
            else "| mean return | - |",
            f"| best return | {best.env_return:+.1f} (episode {r.label(best)}, {best.steps} "
            "steps) |"
            if best
            else "| best return | - |",
            f"| actions by policy / teacher | {r.actions['policy']} / {r.actions['teacher']} |",
            f"| feedback messages (reward / command) / utterances heard | {len(r.words)} / "
            f"{len(r.commands)} / {len(r.utterances)} |",
            f"| states at the end | {r.states} |",
            "",
        ]
        for picture in pictures.get(name, []):
            lines.append(f"![{picture.stem}]({picture.name})")
        lines.append("")
    return "\n".join(lines)


def _gaps(summary: SessionSummary) -> str:
    if not summary.missed:
        return ""
    return f"; {summary.missed} missed by the logger (marked gaps: it was stopped)"

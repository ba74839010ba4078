"""The fleet's report: the points' tables (Markdown), what ran out first, the profile, and the
capacity curve (a PNG). A latency is given as p50 / p99 with its sample count; a p99 of fewer
than 100 samples is their maximum and is printed as such.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from benchmarks.common import is_max


def print_report(done: list[dict[str, Any]], failed: list[dict[str, Any]]) -> None:
    """The tables, the failed points, what ran out first and the profile."""
    print(markdown(done) if done else "no point measured")
    for f in failed:
        print(f"\n{f['robots']} robots, {f['teachers']} teachers failed: {f['error'][-600:]}")
    first = next((p for p in done if p["limit"]["ran_out"]), None)
    print()
    if first:
        print(
            f"first to run out: {first['limit']['what']} at {first['robots']} robots, "
            f"{first['teachers']} teachers ({', '.join(first['limit']['symptoms'])})"
        )
    else:
        print("nothing ran out at these points")
    for p in done:
        if "profile" in p:
            print(f"\nprofile at {p['robots']} robots, {p['teachers']} teachers:\n")
            print("```\n" + p["profile"] + "\n```")


def _ms(v: float | None) -> str:
    return "-" if v is None else f"{v:.0f}"


def _pair(figures: dict[str, Any], what: str) -> str:
    """`what`'s p50 / p99 with its sample count, e.g. "4 / 41 (n=312)"; with fewer than 100
    samples the p99 is their maximum: "4 / max 41 (n=62)"."""
    n = figures[what + "_n"]
    if not n:
        return "- (n=0)"
    top = "max " if is_max(99, n) else ""
    return f"{_ms(figures[what + '_p50_ms'])} / {top}{_ms(figures[what + '_p99_ms'])} (n={n})"


def markdown(points: list[dict[str, Any]]) -> str:
    lines = _points_table(points)
    lines += ["", "CPU, % of one core (RSS, MB):", ""]
    lines += _cpu_table(points)
    return "\n".join(lines)


def _points_table(points: list[dict[str, Any]]) -> list[str]:
    lines = [
        "| robots | teachers (simulated + browsers) | slowest robot, Hz (steps without a fresh "
        "action) | obs -> action p50 / p99 ms (n) | words said / lost "
        "| browser: said -> understood p50 / p99 ms | browser: said -> feedback "
        "| simulated: said -> understood | simulated: said -> feedback "
        "| page frame age p50 / p99 ms (n) | frames a browser got / s (sent) | limit |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for p in points:
        sims = f" ({p['simulators']} simulators)" if p["simulators"] > 1 else ""
        b, m = p["words_by_teacher_kind"]["browser"], p["words_by_teacher_kind"]["sim"]
        frames = (
            "-"
            if p["frames_per_browser_s"] is None
            else f"{p['frames_per_browser_s']:.0f} ({p['frames_expected_per_browser_s']:.0f})"
        )
        lines.append(
            f"| {p['robots']}{sims} | {p['teachers']} ({p['sim_teachers']} + {p['browsers']}) "
            f"| {p['min_robot_rate_hz']:.2f} ({p['steps_without_action_share']:.0%}) "
            f"| {_pair(p, 'obs_to_action')} | {p['words_said']} / {p['words_lost']} "
            f"| {_pair(b, 'to_notice')} | {_pair(b, 'to_feedback')} "
            f"| {_pair(m, 'to_notice')} | {_pair(m, 'to_feedback')} "
            f"| {_pair(p, 'frame_age')} | {frames} "
            f"| {p['limit']['what']} |"
        )
    return lines


def _cpu_table(points: list[dict[str, Any]]) -> list[str]:
    names = sorted({k for p in points for k in p["cpu_percent"]}, key=_process_order)
    lines = ["| robots x teachers | " + " | ".join(names) + " | machine busy (others) |"]
    lines.append("|---|" + "---|" * (len(names) + 1))
    for p in points:
        cells = [
            f"{p['cpu_percent'][n]:.0f} ({p['rss_mb'][n]:.0f})" if n in p["cpu_percent"] else "-"
            for n in names
        ]
        m = p["machine"]
        lines.append(
            f"| {p['robots']} x {p['teachers']} | "
            + " | ".join(cells)
            + f" | {m['busy_percent']:.0f} of {100 * m['cores']} ({m['others_percent']:.0f}) |"
        )
    return lines


def _process_order(name: str) -> tuple[int, str]:
    order = ["sim", "learner", "arbiter", "speech", "web", "router", "sim-teachers"]
    return (order.index(name), name) if name in order else (len(order), name)


def plot(points: list[dict], path: Path) -> None:
    """The capacity curve: the slowest robot's rate, the machine's load and the word and frame
    latencies against robots (one line per number of teachers)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = (
        ("min_robot_rate_hz", "slowest robot, Hz"),
        ("busy_percent", "machine busy, % of one core"),
        ("word_to_feedback_p99_ms", "word said -> feedback p99 (max of < 100), ms"),
        ("frame_age_p99_ms", "page frame age p99, ms"),
    )
    fig, axes = plt.subplots(1, len(panels), figsize=(4 * len(panels), 3.2))
    for ax, (key, label) in zip(axes, panels, strict=True):
        for m in sorted({p["teachers"] for p in points}):
            mine = sorted(
                (p["robots"], p["machine"][key] if key == "busy_percent" else p.get(key))
                for p in points
                if p["teachers"] == m
            )
            xs = [x for x, y in mine if y is not None]
            ax.plot(xs, [y for _, y in mine if y is not None], marker="o", label=f"{m} teachers")
        ax.set_xlabel("robots")
        ax.set_title(label, fontsize=9)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)

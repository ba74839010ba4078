"""What the benchmarks share: percentiles that say how many samples they stand on, the
counters a service's JSON log ends with, and the environment of a Python process of theirs.

A percentile of n samples is the nearest-rank one; one that falls on the last sample (a p99 of
fewer than 100) is the maximum, and is named so.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def percentile(values: Iterable[float], q: float) -> float | None:
    """The nearest-rank `q`th percentile (q in 0-100); None of no values."""
    ordered = sorted(values)
    if not ordered:
        return None
    return ordered[max(1, math.ceil(q / 100 * len(ordered))) - 1]


def is_max(q: float, n: int) -> bool:
    """Whether the `q`th percentile of `n` samples is their maximum (too few to tell more)."""
    return n > 0 and math.ceil(q / 100 * n) >= n and q < 100


def spread(values: Sequence[float], quantiles: Sequence[float] = (50, 99), unit: str = "ms") -> str:
    """E.g. "p50 4.2 ms, p99 40.5 ms (n=312)", or "p50 4.2 ms, max 40.5 ms (n=62)" when the
    samples are too few for the percentile asked; "none (n=0)" of no samples."""
    if not values:
        return "none (n=0)"
    parts = []
    for q in quantiles:
        name = "max" if is_max(q, len(values)) else f"p{q:g}"
        parts.append(f"{name} {percentile(values, q):.1f} {unit}")
    return f"{', '.join(parts)} (n={len(values)})"


def checkout_environment() -> dict[str, str]:
    """What a Python process of a benchmark's own (not `voxshape`) needs to import this
    checkout's packages from any working directory."""
    given = os.environ.get("PYTHONPATH")
    return {"PYTHONPATH": os.pathsep.join(filter(None, (str(ROOT), given)))}


def last_counters(lines: Iterable[str]) -> dict:
    """The last `counters` entry among JSON log lines (with their fields only)."""
    found: dict = {}
    for line in lines:
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(entry, dict) and entry.get("message") == "counters":
            found = {k: v for k, v in entry.items() if k not in ("time", "level", "logger")}
    return found

"""A replay against the live recording: `voxshape replay` of a session's event log, compared
with what its logger recorded live, entity by entity.
"""

from __future__ import annotations

import json
import subprocess
from collections import Counter
from pathlib import Path

from benchmarks.harness.session import VOXSHAPE, Session

# (`thinned_scans` in recording-stats.json counts those observations); a replay never thins.
THINNED = ("/body", "/scan")


def recording_counts(path: Path) -> dict[str, int]:
    """Rows per entity of a .rrd (temporal data only)."""
    from rerun.chunk import RrdReader

    counts: Counter[str] = Counter()
    for chunk in RrdReader(path).stream().filter(is_static=False):
        counts[chunk.entity_path] += chunk.to_record_batch().num_rows
    return dict(counts)


def compare_replay(session: Session) -> tuple[bool, str]:
    """`voxshape replay` of the event log against the live recording, entity by entity: the
    same rows, but for the scans a lagging live renderer thins (fewer or as many)."""
    output = session.run_dir / "replay.rrd"
    done = subprocess.run(
        [VOXSHAPE, "replay", str(session.run_dir), "--output", str(output)],
        cwd=session.workdir,
        capture_output=True,
        text=True,
        timeout=900,
    )
    if done.returncode != 0:
        return False, f"voxshape replay failed: {done.stderr[-500:]}"
    live, again = recording_counts(session.run_dir / "recording.rrd"), recording_counts(output)
    stats = json.loads((session.run_dir / "recording-stats.json").read_text())
    thinned = int(stats.get("thinned_scans", 0))
    differ, left_out = [], Counter()
    for entity in sorted(set(live) | set(again)):
        a, b = live.get(entity, 0), again.get(entity, 0)
        kind = next((t for t in THINNED if entity.endswith(t)), None)
        if kind is not None and a <= b:
            left_out[kind] += b - a
        elif a != b:
            differ.append(f"{entity}: live {a}, replay {b}")
    for kind, n in left_out.items():  # each thinned observation lacks one row of each
        if n not in (0, thinned):
            differ.append(f"*{kind}: {n} rows fewer live, {thinned} observations thinned")
    summary = (
        f"{len(live)} entities, rows live {sum(live.values())} / replay {sum(again.values())}, "
        f"the difference the {thinned} observations the live renderer thinned"
    )
    return (not differ, summary if not differ else f"{summary}; " + "; ".join(differ[:8]))

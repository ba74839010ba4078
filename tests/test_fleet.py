"""benchmarks/fleet.py at its smallest: one robot, one browser teacher, a few seconds."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_fleet_measures_one_robot_and_one_teacher(tmp_path):
    argv = [sys.executable, str(ROOT / "benchmarks" / "fleet.py"), "--points", "1x1", "--json"]
    argv += ["--seconds", "4", "--warmup", "1", "--profile-seconds", "0"]
    done = subprocess.run(
        [*argv, "--workdir", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=90,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    (point,) = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    for name in ("robots", "teachers", "min_robot_rate_hz", "word_to_feedback_p99_ms"):
        assert name in point
    assert point["words_lost"] == 0
    assert (point["robots"], point["teachers"], point["browsers"]) == (1, 1, 1)
    assert point["min_robot_rate_hz"] > 5  # the robot stepped, near its 10 Hz
    assert point["frames_per_browser_s"] > 5  # the page got the map stream
    assert point["cpu_percent"]["sim"] >= 0 and point["rss_mb"]["learner"] > 0

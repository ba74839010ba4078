"""The fleet benchmark (benchmarks/fleet) at its smallest: one robot, one browser teacher who
says a word every half second on average, a few seconds."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.long
def test_fleet_measures_one_robot_and_one_teacher_and_counts_every_word(tmp_path):
    argv = [sys.executable, "-m", "benchmarks.fleet", "--points", "1x1", "--json"]
    argv += ["--seconds", "8", "--warmup", "1", "--word-every", "0.5", "--profile-seconds", "0"]
    done = subprocess.run(
        [*argv, "--workdir", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    (point,) = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    assert (point["robots"], point["teachers"], point["browsers"]) == (1, 1, 1)
    # Words are said in the counted window (its first 5 s): each one understood and credited
    said = point["words_said"]
    assert said >= 3, point["words_by_teacher_kind"]
    assert point["words_by_teacher_kind"]["browser"]["said"] == said
    assert point["words_lost"] == 0 and point["words_understood"] == said, point
    assert point["word_to_feedback_n"] == said and point["word_to_notice_n"] == said
    assert 0 < point["word_to_feedback_p50_ms"] <= point["word_to_feedback_p99_ms"]
    assert point["min_robot_rate_hz"] > 5  # the robot stepped, near its 10 Hz
    assert point["frames_per_browser_s"] > 5  # the page got the map stream
    assert point["cpu_percent"]["sim"] >= 0 and point["rss_mb"]["learner"] > 0

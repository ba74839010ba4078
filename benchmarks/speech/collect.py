"""What the decision is fitted and judged on: every English clip's segments through
pocketsphinx and a phrase scorer (Whisper or Moonshine), each candidate phrase's margins, and
the time each stage took; one JSON line per segment. fit.py fits and measures every variant of
the decision on one such file without running a model again.

    nice -n 10 .venv/bin/python -m benchmarks.speech.collect DIR --scorer moonshine > m.jsonl
    .venv/bin/python -m benchmarks.speech.collect DIR --scorer whisper --model FOLDER > w.jsonl
    .venv/bin/python -m benchmarks.speech.collect DIR --scorer whisper --load 2 --limit 300

`--load N` runs N CPU-bound processes beside it while it measures (the latency target's "under
load"); `--limit N` takes every k-th clip so that about N are measured.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import sys
import time
from dataclasses import astuple
from pathlib import Path

from benchmarks.speech import scoring
from voxshape.protocol import load_vocabulary
from voxshape.protocol.messages import SAMPLE_RATE
from voxshape.runtime.audio import chunks
from voxshape.services.speech.engines import open_scorer
from voxshape.services.speech.pocketsphinx_engine import PocketsphinxRecognizer
from voxshape.services.speech.segmenter import Segmenter
from voxshape.services.speech.sound_alikes import cmudict


def segments(clip: scoring.Clip) -> list[tuple[object, float]]:
    """The clip's segments as the service finds them in a teacher's stream, each with the
    stream time it was given out at (seconds), as scoring.transcribe_clip does."""
    samples, _ = scoring.as_stream(clip)
    segmenter, step, found = Segmenter(), SAMPLE_RATE // 20, []
    for i, piece in enumerate(chunks(samples, step)):
        at = min((i + 1) * step, len(samples)) / SAMPLE_RATE
        found += [(s, at) for s in segmenter.feed(piece)]
    return found + [(s, len(samples) / SAMPLE_RATE) for s in segmenter.flush()]


def measure(clip: scoring.Clip, first: PocketsphinxRecognizer, second: object) -> list[dict]:
    """One row per segment of the clip: pocketsphinx's phrase and posterior, the scorer's
    candidates (its best phrase and pocketsphinx's) with their margins, its transcript's
    spotted phrase, and the seconds each took."""
    rows = []
    for segment, at in segments(clip):
        samples = segment.samples  # type: ignore[attr-defined]
        t0, c0 = time.perf_counter(), time.process_time()
        heard = first.decode(samples)
        t1, c1 = time.perf_counter(), time.process_time()
        hint = heard[0] if heard else None
        scored = second.likeliest(samples, hint)  # type: ignore[attr-defined]
        t2, c2 = time.perf_counter(), time.process_time()
        candidates = {
            p: astuple(second.margins(scored, p))  # type: ignore[attr-defined]
            for p in sorted({scored.best(), hint} & set(scored.phrases))
        }
        rows.append(
            {
                "file": clip.path.name,
                "at": at,
                "audio_s": len(samples) / SAMPLE_RATE,
                "pocketsphinx": list(heard) if heard else None,
                "pocketsphinx_s": round(t1 - t0, 4),
                "scorer_s": round(t2 - t1, 4),
                "cpu_s": [round(c1 - c0, 4), round(c2 - c1, 4)],  # CPU seconds of each
                "best": scored.best(),
                "candidates": candidates,
                "spotted": list(scored.spotted) if scored.spotted else None,
                "transcript": scored.transcript,
                "alikes": {p: second.has_sound_alikes(p) for p in candidates},  # type: ignore[attr-defined]
            }
        )
    return rows


def _busy(stop: object) -> None:
    """A CPU-bound job: the load the latency target is measured under."""
    x = 0
    while not stop.is_set():  # type: ignore[attr-defined]
        for i in range(100000):
            x = (x * 31 + i) % 1000003


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("fixtures", type=Path)
    parser.add_argument("--scorer", choices=["whisper", "moonshine"], default="whisper")
    parser.add_argument("--model", type=Path, help="the scorer's model folder")
    parser.add_argument("--split", choices=["tune", "held-out", "all"], default="all")
    parser.add_argument("--limit", type=int, default=0, help="about this many clips")
    parser.add_argument("--families", help="comma-separated synthesizer families only")
    parser.add_argument(
        "--own-pace", action="store_true", help="clean clips at the voice's own pace only"
    )
    parser.add_argument("--load", type=int, default=0, help="CPU-bound processes beside it")
    parser.add_argument(
        "--skip", type=Path, action="append", default=[], help="clips already in these rows"
    )
    args = parser.parse_args(argv)
    vocabulary = load_vocabulary()
    clips = [
        c
        for c in scoring.load_clips(args.fixtures)
        if c.language == "en"
        and args.split in ("all", c.split)
        and not (args.own_pace and (c.condition != "clean" or c.speed not in (0, 100)))
        and (not args.families or c.synthesizer in args.families.split(","))
    ]
    if args.limit:
        clips = clips[:: max(1, len(clips) // args.limit)]
    done = {json.loads(line)["file"] for rows in args.skip for line in rows.open()}
    clips = [c for c in clips if c.path.name not in done]
    first = PocketsphinxRecognizer(vocabulary, "en")
    cmudict()
    second = open_scorer(args.scorer, vocabulary, "en", args.model)
    stop = multiprocessing.Event()
    load = [multiprocessing.Process(target=_busy, args=(stop,)) for _ in range(args.load)]
    for p in load:
        p.start()
    start = time.perf_counter()
    try:
        for k, clip in enumerate(clips):
            for row in measure(clip, first, second):
                print(json.dumps(row), flush=True)
            if k % 200 == 0:
                print(f"{k}/{len(clips)} clips, {time.perf_counter() - start:.0f} s, load "
                      f"{os.getloadavg()[0]:.1f}", file=sys.stderr)  # fmt: skip
    finally:
        stop.set()
        for p in load:
            p.join()
    return 0


if __name__ == "__main__":
    sys.exit(main())

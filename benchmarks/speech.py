"""The speech engines on WAV fixtures: accuracy, false accepts, real-time factor.

    .venv/bin/python benchmarks/speech.py                          # the committed fixtures
    .venv/bin/python benchmarks/speech.py --synthesize /tmp/speech   # the larger set first
    .venv/bin/python benchmarks/speech.py --fixtures DIR --json

--synthesize runs tests/fixtures/speech/make_fixtures.py --full DIR (needs espeak-ng and sox;
festival adds two more natural US voices). Engines: pocketsphinx; vosk when VOSK_MODEL_PATH or
--vosk-model points at a model; the mock on the clips' texts. `accuracy` is on clean English
(the phrase exactly), `meaning_accuracy` counts a phrase of the same meaning, and
`false_accept_rate` is on words outside the vocabulary (unrelated and near misses).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from protocol import load_vocabulary  # noqa: E402
from services.speech import bench  # noqa: E402
from services.speech.engines import EngineError, open_recognizer  # noqa: E402
from services.speech.mock import MockRecognizer, MockSettings  # noqa: E402
from services.speech.pocketsphinx_engine import PocketsphinxSettings  # noqa: E402

FIXTURES = ROOT / "tests" / "fixtures" / "speech"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fixtures", type=Path, default=FIXTURES)
    parser.add_argument("--synthesize", type=Path, metavar="DIR", help="make the larger set")
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    parser.add_argument("--vosk-model", type=Path, default=os.environ.get("VOSK_MODEL_PATH"))
    parser.add_argument("--distractors", type=int, default=PocketsphinxSettings().distractors)
    parser.add_argument(
        "--distractor-weight", type=float, default=PocketsphinxSettings().distractor_weight
    )
    parser.add_argument("--mock-error-rate", type=float, default=0.2)
    args = parser.parse_args()
    folder = args.fixtures
    if args.synthesize:
        script = FIXTURES / "make_fixtures.py"
        subprocess.run([sys.executable, str(script), "--full", str(args.synthesize)], check=True)
        folder = args.synthesize
    vocabulary = load_vocabulary()
    clips = bench.load_clips(folder)
    results = []
    settings = PocketsphinxSettings(args.distractors, args.distractor_weight)
    engines = [("pocketsphinx", "en", None)]
    if args.vosk_model:
        engines += [("vosk", "en", args.vosk_model), ("vosk", "es", args.vosk_model)]
    for engine, language, model in engines:
        try:
            t0 = time.perf_counter()
            recognizer = open_recognizer(engine, vocabulary, language, model, None, settings)
            load_s = time.perf_counter() - t0
        except EngineError as e:
            print(f"{engine} ({language}): skipped: {e}", file=sys.stderr)
            continue
        summary = bench.run(clips, recognizer).summary(vocabulary)
        summary["language"], summary["load_s"] = language, round(load_s, 2)
        results.append(summary)
    mock = MockRecognizer(vocabulary, MockSettings(error_rate=args.mock_error_rate, seed=0))
    summary = bench.run_mock(clips, mock).summary(vocabulary)
    summary["error_rate_setting"] = args.mock_error_rate
    results.append(summary)
    if args.json:
        print(json.dumps({"fixtures": str(folder), "clips": len(clips), "engines": results}))
    else:
        print(f"{len(clips)} clips in {folder}")
        for r in results:
            print_summary(r)
    return 0


def print_summary(r: dict) -> None:
    print(
        f"\n{r['engine']}: accuracy {r['accuracy']} (same meaning {r['meaning_accuracy']}) on "
        f"clean English, false accepts {r['false_accept_rate']} outside the vocabulary, "
        f"real-time factor {r['realtime_factor']}, onset error p50 {r['onset_error_p50_s']} s"
    )
    print(f"  {'group':<48} {'n':>4} {'accuracy':>9} {'meaning':>8} {'accepted':>9}")
    for name, g in r["groups"].items():
        print(
            f"  {name:<48} {g['n']:>4} {_f(g['accuracy']):>9} {_f(g['meaning_accuracy']):>8} "
            f"{_f(g['accept_rate']):>9}"
        )


def _f(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


if __name__ == "__main__":
    sys.exit(main())

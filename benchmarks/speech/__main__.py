"""The speech engines on WAV fixtures: accuracy, false accepts, latency, real-time factor.

    .venv/bin/python -m benchmarks.speech                            # the committed fixtures
    .venv/bin/python -m benchmarks.speech --synthesize /tmp/speech   # the larger set first
    .venv/bin/python -m benchmarks.speech --fixtures DIR --split tune --language es
    .venv/bin/python -m benchmarks.speech --fixtures DIR --markdown  # docs/speech.md's tables
    .venv/bin/python -m benchmarks.speech --fixtures DIR --engine default  # what runs by default
    .venv/bin/python -m benchmarks.speech --tables run.json --markdown  # a --json run's tables

--synthesize runs tests/fixtures/speech/make_fixtures.py --full DIR (needs espeak-ng, sox and
festival); `python -m benchmarks.speech.synthesize --out DIR` makes the clips of every voice
family instead (voices.py), and collect.py with fit.py fit decision.py's constants on them.
Clips are split: "tune" is what engine settings may be chosen on, "held-out" (other voices,
other outside words, level/telephone/reverb conditions) is never looked at while tuning;
--split measures one of them only. Engines: the cascade (the default of `voxshape speech`:
pocketsphinx, then Whisper) and pocketsphinx in English and in Spanish; whisper in
English when installed (pip install -e '.[whisper]'); vosk in both when VOSK_MODEL_PATH or
--vosk-model points at a model; --engine and --language keep some of them (`--engine default`:
whatever `voxshape speech` runs by default). The mock runs on the clips' texts.

Per engine: `accuracy` is on the tuning split's clean speech in the engine's language (the
phrase exactly), `meaning_accuracy` counts a phrase of the same meaning, `held_out_accuracy` is
the same on the held-out voices; `false_accept_rate` (and `held_out_false_accept_rate`) is on
everything outside the engine's vocabulary: unrelated words, near misses, and speech in the
other language (unless heard as a phrase of the same meaning). Latency runs from the end of
the speech to the utterance: the segmenter's wait plus decoding. For the cascade, the share
of utterances that reached Whisper and the CPU seconds of each stage.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from benchmarks.speech import scoring  # noqa: E402
from voxshape.protocol import Vocabulary, load_vocabulary  # noqa: E402
from voxshape.services.speech.engines import open_recognizer  # noqa: E402
from voxshape.services.speech.mock import MockRecognizer, MockSettings  # noqa: E402
from voxshape.services.speech.pocketsphinx_engine import PocketsphinxSettings  # noqa: E402
from voxshape.services.speech.recognizer import DEFAULT_ENGINE, EngineError  # noqa: E402

FIXTURES = ROOT / "tests" / "fixtures" / "speech"
ENGINES = [
    ("cascade", "en"),
    ("cascade", "es"),
    ("pocketsphinx", "en"),
    ("pocketsphinx", "es"),
    ("whisper", "en"),
    ("vosk", "en"),
    ("vosk", "es"),
]


def main() -> int:
    args = _parser().parse_args()
    if args.tables:  # the tables of a run saved with --json
        saved = json.loads(args.tables.read_text())
        counts = Counter(saved["splits"])
        _print_results(
            args, Path(saved["fixtures"]), saved["synthesis_s"], counts, saved["engines"]
        )
        return 0
    folder, synthesis_s = _fixtures(args)
    vocabulary = load_vocabulary()
    clips = [c for c in scoring.load_clips(folder) if args.split in ("all", c.split)]
    results = _measure_engines(args, vocabulary, clips)
    mock = MockRecognizer(vocabulary, MockSettings(error_rate=args.mock_error_rate, seed=0))
    summary = scoring.run_mock(clips, mock).summary(vocabulary)
    summary["error_rate_setting"] = args.mock_error_rate
    results.append(summary)
    _print_results(args, folder, synthesis_s, Counter(c.split for c in clips), results)
    return 0


def _parser() -> argparse.ArgumentParser:
    """The command line, as the module's docstring shows it."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fixtures", type=Path, default=FIXTURES)
    parser.add_argument("--synthesize", type=Path, metavar="DIR", help="make the larger set")
    parser.add_argument("--split", choices=["tune", "held-out", "all"], default="all")
    parser.add_argument("--language", choices=["en", "es", "all"], default="all")
    output = parser.add_mutually_exclusive_group()
    output.add_argument("--json", action="store_true", help="one JSON object on stdout")
    output.add_argument("--markdown", action="store_true", help="tables for docs/speech.md")
    parser.add_argument(
        "--engine",
        choices=["all", "default", *dict(ENGINES)],
        default="all",
        help=f"all: each installed; default: what `voxshape speech` runs ({DEFAULT_ENGINE})",
    )
    parser.add_argument("--vosk-model", type=Path, default=os.environ.get("VOSK_MODEL_PATH"))
    parser.add_argument("--distractors", type=int, help="default: each language's own")
    parser.add_argument("--distractor-weight", type=float, help="default: the engine's")
    parser.add_argument(
        "--raw-confidence",
        action="store_true",
        help="pocketsphinx's lattice posterior as confidence (to calibrate it)",
    )
    parser.add_argument("--mock-error-rate", type=float, default=0.2)
    parser.add_argument(
        "--tables", type=Path, metavar="JSON", help="print the tables of a run saved with --json"
    )
    return parser


def _fixtures(args: argparse.Namespace) -> tuple[Path, float | None]:
    """The folder of clips, synthesized first with --synthesize (and the seconds it took)."""
    if not args.synthesize:
        return args.fixtures, None
    script = FIXTURES / "make_fixtures.py"
    t0 = time.perf_counter()
    subprocess.run([sys.executable, str(script), "--full", str(args.synthesize)], check=True)
    return args.synthesize, round(time.perf_counter() - t0, 1)


def _measure_engines(
    args: argparse.Namespace, vocabulary: Vocabulary, clips: list[scoring.Clip]
) -> list[dict]:
    """Each engine asked for on the clips, with the seconds it took to load and to run; one
    that cannot be opened is skipped, said on stderr, as is vosk without a model."""
    # only the settings given on the command line; the rest are each engine's defaults
    given = {"distractors": args.distractors, "distractor_weight": args.distractor_weight}
    given["calibrated"] = False if args.raw_confidence else None
    settings = PocketsphinxSettings(**{k: v for k, v in given.items() if v is not None})
    results = []
    wanted = DEFAULT_ENGINE if args.engine == "default" else args.engine
    for engine, language in ENGINES:
        if args.language not in ("all", language) or wanted not in ("all", engine):
            continue
        if engine == "vosk" and not args.vosk_model:
            continue
        model = args.vosk_model if engine == "vosk" else None
        try:
            t0 = time.perf_counter()
            recognizer = open_recognizer(engine, vocabulary, language, model, None, settings)
            load_s = time.perf_counter() - t0
        except EngineError as e:
            print(f"{engine} ({language}): skipped: {e}", file=sys.stderr)
            continue
        t0 = time.perf_counter()
        summary = scoring.run(clips, recognizer).summary(vocabulary)
        summary["load_s"], summary["run_s"] = round(load_s, 2), round(time.perf_counter() - t0)
        if stats := getattr(recognizer, "stats", None):  # the cascade's
            summary["to_whisper_share"] = round(stats.to_whisper / max(1, stats.utterances), 3)
            summary["cpu_s"] = {stage: round(s, 1) for stage, s in stats.cpu_s.items()}
        print(f"{engine} ({language}): {len(clips)} clips in {summary['run_s']} s", file=sys.stderr)
        results.append(summary)
    return results


def _print_results(
    args: argparse.Namespace,
    folder: Path,
    synthesis_s: float | None,
    counts: Counter[str],
    results: list[dict],
) -> None:
    """One JSON object (--json), or a line on the clips and each engine's tables."""
    if args.json:
        head = {"fixtures": str(folder), "clips": counts.total(), "splits": counts}
        print(json.dumps({**head, "synthesis_s": synthesis_s, "engines": results}))
        return
    made = f", synthesized in {synthesis_s} s" if synthesis_s is not None else ""
    splits = ", ".join(f"{n} {s}" for s, n in sorted(counts.items(), reverse=True))
    print(f"{counts.total()} clips ({splits}) in {folder}{made}")
    for r in results:
        (print_markdown if args.markdown else print_summary)(r)


def _name(r: dict) -> str:
    return f"{r['engine']} ({r['language']})" if r["language"] else r["engine"]


def _headline(r: dict) -> str:
    language = {"en": "English", "es": "Spanish", None: "English"}.get(r["language"], "")
    return (
        f"accuracy {_f(r['accuracy'])} (same meaning {_f(r['meaning_accuracy'])}) on clean "
        f"{language} of the tuning voices, {_f(r['held_out_accuracy'])} "
        f"({_f(r['held_out_meaning_accuracy'])}) of the held-out ones; false accepts "
        f"{_f(r['false_accept_rate'])} tune, {_f(r['held_out_false_accept_rate'])} held out; "
        f"latency p50 {_f(r['latency_p50_s'])} s, p95 {_f(r['latency_p95_s'])} s "
        f"(n={r['latency_n']}); "
        f"real-time factor {r['realtime_factor']}; onset error p50 {r['onset_error_p50_s']} s"
    )


def _rows(r: dict, table: str) -> list[tuple[str, str, dict]]:
    """(split, name, figures) of the conditions or voices table; the mock's names carry the
    language, as it hears every language."""
    rows = []
    for split, languages in r[table].items():
        for language, groups in languages.items():
            for name, g in groups.items():
                rows.append((split, name if r["language"] else f"{language} {name}", g))
    return rows


def _cascade(r: dict) -> str:
    """The cascade's share of utterances that reached Whisper and each stage's CPU."""
    if "to_whisper_share" not in r:
        return ""
    cpu = ", ".join(f"{stage} {s} s" for stage, s in r["cpu_s"].items())
    return f"; {r['to_whisper_share']:.0%} of the utterances reached Whisper (CPU: {cpu})"


def print_summary(r: dict) -> None:
    print(f"\n{_name(r)}: {_headline(r)}{_cascade(r)}")
    print(f"  {'split':<9} {'condition or voice (clean)':<40} {'n':>4} {'accuracy':>9} "
          f"{'meaning':>8} {'accepted':>9}")  # fmt: skip
    for split, name, g in _rows(r, "conditions") + _rows(r, "voices"):
        print(
            f"  {split:<9} {name:<40} {g['n']:>4} {_f(g['accuracy']):>9} "
            f"{_f(g['meaning_accuracy']):>8} {_f(g['accept_rate']):>9}"
        )
    for split, kinds in [(s, k) for s, k in r["false_accepts"].items() if k]:
        accepted = ", ".join(f"{k} {g['accepted']}/{g['n']}" for k, g in kinds.items())
        print(f"  false accepts, {split}: {accepted}")


def print_markdown(r: dict) -> None:
    print(f"\n### {_name(r)}\n\n{r['clips']} clips. {_headline(r)}{_cascade(r)}.")
    if "run_s" in r:
        print(f"Loaded in {r['load_s']} s, measured in {r['run_s']} s.")
    tables = [("conditions", "condition"), ("voices", "voice (clean)")]
    for table, title in tables[: 2 if r["language"] else 1]:
        print(
            f"\n| split | {title} | n | accuracy | meaning | accepted |\n|---|---|---|---|---|---|"
        )
        for split, name, g in _rows(r, table):
            figures = (g["accuracy"], g["meaning_accuracy"], g["accept_rate"])
            print(f"| {split} | {name} | {g['n']} | " + " | ".join(map(_f, figures)) + " |")
    kinds = ["unrelated", "near", scoring.OTHER_LANGUAGE]
    print(f"\n| false accepts | {' | '.join(kinds)} |\n|---|---|---|---|")
    for split, found in [(s, f) for s, f in r["false_accepts"].items() if f]:
        cells = [_share(found[k]) if k in found else "-" for k in kinds]
        print(f"| {split} | {' | '.join(cells)} |")
    if r["language"] is None:
        return  # the mock takes text: no latency, and its per-phrase figures are its dice
    print(
        "\n| latency p50 | latency p95 | utterances | real-time factor | onset error p50 |\n"
        "|---|---|---|---|---|"
    )
    print(
        f"| {_f(r['latency_p50_s'])} s | {_f(r['latency_p95_s'])} s | {r['latency_n']} | "
        f"{r['realtime_factor']} | {_f(r['onset_error_p50_s'])} s |"
    )
    _print_reliability(r)
    _print_synthesizers(r)
    _print_confusion(r)
    _print_kind_pairs(r)
    print("\n| phrase | tuning accuracy | held-out accuracy |\n|---|---|---|")
    for word, by_split in r["per_word_accuracy"].items():
        print(f"| {word.split(':', 1)[1]} | {_f(by_split['tune'])} | {_f(by_split['held-out'])} |")
    _print_sentences(r)


def _print_reliability(r: dict) -> None:
    """Of the phrases recognized with a confidence in each band, how many were right: the
    reliability diagram as a table (the mean confidence against the share right)."""
    bands = list(scoring.CONFIDENCE_BANDS)
    print("\n| split | confidence from | recognized | mean confidence | right |")
    print("|---|---|---|---|---|")
    for split, found in [(s, f) for s, f in r["calibration"].items() if f]:
        for band in bands:
            g = found.get(f"{band:g}")
            if g:
                print(
                    f"| {split} | {band:g} | {g['n']} | {_f(g['confidence'])} | {_f(g['share'])} |"
                )


def _print_synthesizers(r: dict) -> None:
    kinds = ["clean", "near", "unrelated", scoring.SENTENCE]
    print(
        "\n| split | synthesizer | clean speech heard | near misses accepted | unrelated "
        "accepted | sentences credited right |\n|---|---|---|---|---|---|"
    )
    for split, synthesizers in r["synthesizers"].items():
        for name, found in synthesizers.items():
            cells = [_share(found[k], "share") if k in found else "-" for k in kinds]
            print(f"| {split} | {name} | {' | '.join(cells)} |")


def _print_confusion(r: dict) -> None:
    """What became of vocabulary speech, by kind of word: the mock's confusion model's terms."""
    outcomes = ["right", "dropped", "misheard, same kind", "misheard, other kind", "inserted"]
    print(f"\n| split | kind of word | n | {' | '.join(outcomes)} |\n|---|---|---|{'---|' * 5}")
    for split, kinds in r.get("confusion", {}).items():
        for kind, counts in kinds.items():
            n = sum(counts.values())
            cells = [_f(counts.get(o, 0) / n) for o in outcomes]
            print(f"| {split} | {kind} | {n} | {' | '.join(cells)} |")


def _print_kind_pairs(r: dict) -> None:
    """Each judgement heard as a command, or the reverse: which phrase as which, how often,
    against the vocabulary clips of the split."""
    n = {
        split: sum(sum(c.values()) for c in kinds.values())
        for split, kinds in r["confusion"].items()
    }
    print(
        "\n| split | judgement <-> command | clips | of the vocabulary clips |\n|---|---|---|---|"
    )
    for split, pairs in r.get("kind_pairs", {}).items():
        total = sum(pairs.values())
        cells = ", ".join(f"{pair} ({k})" for pair, k in pairs.items()) or "none"
        print(f"| {split} | {cells} | {total} | {total}/{n.get(split, 0)} |")


def _print_sentences(r: dict) -> None:
    rows = [(s, t, g) for s, found in r["sentences"].items() for t, g in found.items()]
    if rows:
        print("\n| split | sentence | credited right |\n|---|---|---|")
        for split, text, g in rows:
            print(f"| {split} | {text} | {g['right']}/{g['n']} |")


def _share(g: dict, key: str = "rate") -> str:
    count = f" ({g['accepted']}/{g['n']})" if "accepted" in g else f" (n={g['n']})"
    return f"{_f(g[key])}{count}"


def _f(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


if __name__ == "__main__":
    sys.exit(main())

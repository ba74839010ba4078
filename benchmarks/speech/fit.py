"""Fits the decision (voxshape/services/speech/decision.py) on the tuning split of a
collect.py run, and measures each variant of the engine on both splits, without running a
model again: which stages pay.

    .venv/bin/python -m benchmarks.speech.fit ROWS.jsonl --fixtures DIR            # variants
    .venv/bin/python -m benchmarks.speech.fit ROWS.jsonl --fixtures DIR --json OUT  # + tables

A variant is which stages decide (`VARIANTS`): pocketsphinx alone; the scorer alone, with or
without the sound-alike margins and the prior-corrected one; the cascade (pocketsphinx's say
as features). Each is fitted on
the tuning clips alone: a logistic regression of its margins (a candidate is right when it is
the clip's phrase, or of the meaning its sentence credits), `accept` the lowest confidence at
which at most `NEAR_MISSES` of the tuning near misses pass (0.08, for at most 0.10 on voices
never tuned on), `kind_margin` the least margin over the other kind's likeliest phrase, from
`KIND_FLOOR`, at which no tuning clip is heard as the other kind (but those a phrase spotted
in a sentence brings, which no margin stops). The
engine's own decision (decision.choose) then runs on every segment, and scoring.Report says
what came of each clip, with latency and real-time factor from each stage's measured time.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from benchmarks.speech import scoring
from voxshape.protocol import Vocabulary, load_vocabulary
from voxshape.protocol.vocabulary import normalize
from voxshape.services.speech import decision
from voxshape.services.speech.decision import DecisionRule, Margins
from voxshape.services.speech.pocketsphinx_engine import PRECISION_BY_POSTERIOR

NEAR_MISSES = 0.08  # the share of tuning near misses the threshold may let through, at most
KIND_FLOOR = 2.0  # nats: a phrase of the other kind is e^2 = 7 times less likely, at least
L2 = 0.01
_VOCABULARY = load_vocabulary()
KINDS = {  # phrase -> command or judgement, as the engine's scorer has them
    p: decision.kind_of(m.kind) for p in _VOCABULARY.phrases("en") if (m := _VOCABULARY.lookup(p))
}
FEATURES = (
    "free", "sound_alike", "other_phrase", "ps_agrees", "ps_posterior", "prior", "transcribed",
    "words",
)  # fmt: skip


@dataclass(frozen=True)
class Variant:
    name: str
    features: tuple[str, ...]  # of FEATURES
    pocketsphinx: bool = True  # its phrase is a candidate (and its say a feature, if used)
    scorer: bool = True


SCORER = ("free", "other_phrase", "transcribed", "words")  # what any scorer gives
ALIKE = ("sound_alike",)
PS = ("ps_agrees", "ps_posterior")
VARIANTS = [
    Variant("pocketsphinx alone", (), scorer=False),
    Variant("scorer alone", SCORER, False),
    Variant("scorer + sound-alikes", (*SCORER, *ALIKE), False),
    Variant("scorer + sound-alikes + prior-corrected", (*SCORER, *ALIKE, "prior"), False),
    Variant("cascade, margins only (the landed features)", ("free", "other_phrase", *ALIKE, *PS)),
    Variant("cascade without sound-alikes", (*SCORER, *PS)),
    Variant("cascade", (*SCORER, *ALIKE, *PS)),
    Variant("cascade + prior-corrected", (*SCORER, *ALIKE, *PS, "prior")),
    Variant("cascade + prior-corrected, no raw sound-alike margin", (*SCORER, *PS, "prior")),
]


def load_rows(paths: list[Path], clips: dict[str, scoring.Clip]) -> list[tuple[scoring.Clip, list]]:
    """collect.py's rows, by clip, in the order of the files."""
    by_clip: dict[str, list] = {}
    for line in (line for path in paths for line in path.read_text().splitlines()):
        if line.startswith("{"):
            row = json.loads(line)
            by_clip.setdefault(row["file"], []).append(row)
    return [(clips[f], rows) for f, rows in by_clip.items() if f in clips]


def candidates(row: dict, v: Variant) -> list[tuple[str, Margins]]:
    """The variant's candidates in a segment, with its margins (pocketsphinx's say set)."""
    heard = row["pocketsphinx"] if v.pocketsphinx else None
    hint, posterior = heard if heard else (None, 0.0)
    out = []
    for phrase, values in row["candidates"].items():
        if phrase != row["best"] and phrase != hint:
            continue
        margins = Margins(*values[:7])
        if phrase == hint:
            margins = replace(margins, pocketsphinx_agrees=1.0, pocketsphinx_posterior=posterior)
        said = float(row["transcript"] == normalize(phrase))
        out.append((phrase, replace(margins, transcribed=said, words=len(phrase.split()))))
    return out


def weights_of(v: Variant, fitted: np.ndarray) -> tuple[float, ...]:
    """The full weight tuple of decision.py: the variant's fitted ones, 0 for the others."""
    full = dict(zip(v.features, fitted[:-1], strict=True))
    return (*(round(float(full.get(f, 0.0)), 3) for f in FEATURES), round(float(fitted[-1]), 3))


def decide(row: dict, v: Variant, d: DecisionRule) -> tuple[tuple[str, float] | None, float]:
    """What the variant's engine hears in a segment, and the seconds it took."""
    heard = row["pocketsphinx"]
    ps_s = row["pocketsphinx_s"] if v.pocketsphinx else 0.0
    if not v.scorer:
        if heard is None:
            return None, ps_s
        return (heard[0], next(p for b, p in PRECISION_BY_POSTERIOR if heard[1] >= b)), ps_s
    took = ps_s + row["scorer_s"]
    chosen = decision.choose(candidates(row, v), d, KINDS)
    if chosen is None and row["spotted"] and row["spotted"][1] >= decision.SPOT_MARGIN:
        chosen = (row["spotted"][0], d.accept)
    return chosen, took


def outcomes(data: list, v: Variant, d: DecisionRule, split: str | None = None) -> list:
    """scoring.Outcome of every clip (of `split`) under the variant's engine."""
    out = []
    for clip, rows in data:
        if split and clip.split != split:
            continue
        offset = scoring.QUIET_S if clip.noise == "none" else 0.0
        heard, recognized, spent, audio, latency = [], [], 0.0, 0.0, None
        for row in rows:
            chosen, took = decide(row, v, d)
            spent, audio = spent + took, audio + row["audio_s"]
            if chosen is not None:
                recognized.append(chosen)
                heard.append(chosen[0])
                latency = row["at"] + took - (offset + clip.speech_end_s)
        out.append(scoring.Outcome(clip, heard, None, spent, audio, latency, recognized))
    return out


def right(clip: scoring.Clip, phrase: str, vocabulary: Vocabulary) -> bool:
    if clip.kind == "vocabulary":
        return phrase == clip.text
    meaning = vocabulary.lookup(phrase)
    return clip.kind == "sentence" and meaning is not None and meaning.name == clip.credits


def logistic(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Logistic regression by Newton's method, a little L2 on the weights (not the bias)."""
    x1 = np.hstack([x, np.ones((len(x), 1))])
    penalty = L2 * np.diag([*np.ones(x.shape[1]), 0.0])
    w = np.zeros(x1.shape[1])
    for _ in range(50):
        p = 1.0 / (1.0 + np.exp(-np.clip(x1 @ w, -30, 30)))
        gradient = x1.T @ (p - y) + penalty @ w
        hessian = x1.T @ (x1 * (p * (1 - p))[:, None]) + penalty
        w -= np.linalg.solve(hessian + 1e-9 * np.eye(len(w)), gradient)
    return w


def fit_variant(
    data: list, v: Variant, vocabulary: Vocabulary, near_misses: float = NEAR_MISSES
) -> DecisionRule:
    """The variant's weights, accept and kind_margin, from the tuning clips alone."""
    tune = [(c, rows) for c, rows in data if c.split == "tune"]
    if not v.scorer:
        return DecisionRule((0.0,) * (len(FEATURES) + 1), 0.5)
    x, y = [], []
    for clip, rows in tune:
        for row in rows:
            for phrase, m in candidates(row, v):
                features = dict(zip(FEATURES, m.features(), strict=True))
                x.append([features[f] for f in v.features])
                y.append(right(clip, phrase, vocabulary))
    weights = weights_of(v, logistic(np.array(x, float), np.array(y, float)))
    near = [(c, r) for c, r in tune if c.kind == "near"]
    accept = 0.99
    for a in np.arange(0.5, 0.995, 0.01):
        passed = [bool(o.heard) for o in outcomes(near, v, DecisionRule(weights, float(a)))]
        if np.mean(passed) <= near_misses:
            accept = round(float(a), 2)
            break
    said = [(c, r) for c, r in tune if c.kind == "vocabulary"]

    def confused(k: float) -> int:  # tuning clips heard as the other kind
        outs = outcomes(said, v, DecisionRule(weights, accept, k))
        return sum(bool(other_kind(o, vocabulary)) for o in outs)

    least = confused(decision.MARGIN_CAP)  # a phrase spotted in a sentence escapes the rule
    k = next(k for k in np.arange(KIND_FLOOR, 8.01, 0.25) if confused(float(k)) <= least)
    return DecisionRule(weights, accept, float(k))


def other_kind(o: scoring.Outcome, vocabulary: Vocabulary) -> list[str]:
    """The phrases heard in a vocabulary clip that are of the other kind than the one said."""
    said = vocabulary.lookup(o.clip.text)
    kind = decision.kind_of(said.kind) if said else ""
    return [h for h in o.heard if (m := vocabulary.lookup(h)) and decision.kind_of(m.kind) != kind]


UNTUNED = ("flite", "pico", "piper")


def figures(outs: list[scoring.Outcome], vocabulary: Vocabulary) -> dict:
    """The issue's targets on held-out clips: per family of voices never tuned on (and all
    held-out voices together), and the real recordings."""
    out: dict = {}
    scopes = {f: [o for o in outs if o.clip.synthesizer == f] for f in UNTUNED}
    scopes["untuned together"] = [o for o in outs if o.clip.synthesizer in UNTUNED]
    scopes["every held-out voice"] = [o for o in outs if o.clip.synthesizer != "recorded"]
    for name, group in scopes.items():
        if group:
            out[name] = _targets(group, vocabulary)
    real = [o for o in outs if o.clip.synthesizer == "recorded"]
    out["recorded"] = {"unrelated": _share([bool(o.heard) for o in real])}
    return out


def _targets(outs: list[scoring.Outcome], vocabulary: Vocabulary) -> dict:
    said = [o for o in outs if o.clip.kind == "vocabulary"]
    clean = [o for o in said if o.clip.condition == "clean"]
    ok = {id(o): [h for h in o.heard] == [o.clip.text] for o in said}
    words = {t: [ok[id(o)] for o in said if o.clip.text == t] for t in {o.clip.text for o in said}}
    conditions = {
        c: [ok[id(o)] for o in said if o.clip.condition == c] for c in scoring_conditions(said)
    }
    pairs: dict[str, int] = {}
    for o in said:
        for h in other_kind(o, vocabulary):
            pairs[f"{o.clip.text} -> {h}"] = pairs.get(f"{o.clip.text} -> {h}", 0) + 1
    worst = sorted(words, key=lambda t: (np.mean(words[t]), t))[:5]  # ties by name
    latencies = [o.latency_s for o in outs if o.latency_s is not None]
    return {
        "clean": _share([ok[id(o)] for o in clean]),
        "every clip": _share(list(ok.values())),
        "worst words": {t: _share(words[t]) for t in worst},
        "phrases under 0.80": sorted(t for t in words if np.mean(words[t]) < 0.8),
        "phrases": len(words),
        "conditions": {c: _share(v) for c, v in conditions.items()},
        "near": _share([bool(o.heard) for o in outs if o.clip.kind == "near"]),
        "unrelated": _share([bool(o.heard) for o in outs if o.clip.kind == "oov"]),
        "other kind": {"n": len(said), "heard": sum(pairs.values()), "pairs": pairs},
        "rtf": round(sum(o.recognize_s for o in outs) / max(1e-9, sum(o.audio_s for o in outs)), 4),
        "latency p95": round(float(np.percentile(latencies, 95)), 3) if latencies else None,
    }


def scoring_conditions(outs: list[scoring.Outcome]) -> list[str]:
    return sorted({o.clip.condition for o in outs})


def _share(values: list[bool]) -> list:
    """[share, n]."""
    return [round(float(np.mean(values)), 3) if values else None, len(values)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("rows", type=Path, nargs="+", help="collect.py's output (files)")
    parser.add_argument("--fixtures", type=Path, required=True, help="the clips' folder")
    parser.add_argument("--variant", help="only this one (a name of VARIANTS)")
    parser.add_argument(
        "--near", type=float, default=NEAR_MISSES, help="tuning near misses let through, at most"
    )
    parser.add_argument("--json", type=Path, help="write every variant's figures here")
    parser.add_argument(
        "--tables",
        type=Path,
        help="write the variant's run as `python -m benchmarks.speech --tables` reads it",
    )
    parser.add_argument("--name", default="cascade", help="the engine's name in --tables")
    parser.add_argument(
        "--speed", action="store_true", help="only the real-time factor and latency of the rows"
    )
    parser.add_argument(
        "--markdown",
        action="store_true",
        help="each variant's targets as a table of docs/speech.md",
    )
    args = parser.parse_args(argv)
    vocabulary = load_vocabulary()
    clips = {c.path.name: c for c in scoring.load_clips(args.fixtures)}
    data = load_rows(args.rows, clips)
    if args.speed:
        print(speed(data))
        return 0
    results, kept = {}, []
    for v in VARIANTS:
        if args.variant and v.name != args.variant:
            continue
        d = fit_variant(data, v, vocabulary, args.near)
        held = outcomes(data, v, d, "held-out")
        tune = outcomes(data, v, d, "tune")
        kept = [("held-out", held), ("tune", tune)]
        results[v.name] = {
            "decision": {"weights": d.weights, "accept": d.accept, "kind_margin": d.kind_margin},
            "held-out": figures(held, vocabulary),
            "tune": _targets(tune, vocabulary),
            "report": scoring.Report("fit", "en", held + tune).summary(vocabulary),
        }
        print(
            markdown(v.name, results[v.name])
            if args.markdown
            else headline(v.name, results[v.name])
        )
    if args.tables and len(results) == 1:
        report = scoring.Report(args.name, "en", [o for _, outs in kept for o in outs])
        counts = {s: sum(c.split == s for c, _ in data) for s in scoring.SPLITS}
        run = {"fixtures": str(args.fixtures), "synthesis_s": None, "splits": counts}
        args.tables.write_text(json.dumps({**run, "engines": [report.summary(vocabulary)]}))
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


def speed(data: list) -> str:
    """The cascade's real-time factor (pocketsphinx and the scorer on every segment) and its
    latency from the end of the speech, were every segment of a vocabulary clip heard."""
    took = [(r["pocketsphinx_s"] + r["scorer_s"], r["audio_s"]) for _, rows in data for r in rows]
    latencies = [
        r["at"] + r["pocketsphinx_s"] + r["scorer_s"] - (scoring.QUIET_S * (c.noise == "none"))
        - c.speech_end_s
        for c, rows in data
        if c.kind == "vocabulary"
        for r in rows
    ]  # fmt: skip
    rtf = sum(t for t, _ in took) / sum(a for _, a in took)
    p50, p95 = np.percentile(latencies, [50, 95])
    cpu = [(sum(r["cpu_s"]), r["audio_s"]) for _, rows in data for r in rows if "cpu_s" in r]
    per_audio = (
        f"; CPU {sum(c for c, _ in cpu) / sum(a for _, a in cpu):.3f} s an audio second"
        if cpu
        else ""
    )
    return (
        f"{len(took)} segments: real-time factor {rtf:.3f}; latency p50 {p50:.3f} s, "
        f"p95 {p95:.3f} s ({len(latencies)} segments of vocabulary clips){per_audio}"
    )


TARGETS = "clean 0.92, every phrase 0.80, every condition 0.80, near 0.10, unrelated 0.03"


def markdown(name: str, r: dict) -> str:
    """The issue's targets on the held-out clips, a row per family never tuned on."""
    rows = [
        f"\n{name} (threshold {r['decision']['accept']}, {r['decision']['kind_margin']} nats "
        f"over the other kind); targets: {TARGETS}, judgement <-> command 1 in 200\n",
        "| held out | clean | every clip | phrases under 0.80 | worst phrases | worst condition "
        "| near misses | unrelated | judgement <-> command | RTF / p95 latency |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for scope, f in r["held-out"].items():
        if scope == "recorded":
            rows.append(
                f"| real recordings (Allison Smith) | - | - | - | - | - | - | "
                f"{_cell(f['unrelated'])} | - | - |"
            )
            continue
        worst = ", ".join(f"{t} {s[0]:.2f}" for t, s in list(f["worst words"].items())[:3])
        conditions = {c: s for c, s in f["conditions"].items() if c != "clean"}
        low = min(conditions.items(), key=lambda c: c[1][0], default=None)
        cond = f"{low[0]} {low[1][0]:.2f}" if low else "-"
        kind = f"{f['other kind']['heard']}/{f['other kind']['n']}"
        under = f"{len(f['phrases under 0.80'])} of {f['phrases']}"
        rows.append(
            f"| {scope} | {_cell(f['clean'])} | {_cell(f['every clip'])} | {under} | {worst} | "
            f"{cond} | {_cell(f['near'])} | "
            f"{_cell(f['unrelated'])} | {kind} | {f['rtf']} / {f['latency p95']} s |"
        )
    return "\n".join(rows)


def _cell(share: list) -> str:
    return "-" if share[0] is None else f"{share[0]:.3f} (n={share[1]})"


def headline(name: str, r: dict) -> str:
    """One paragraph: the decision and the held-out figures that the targets are about."""
    d = r["decision"]
    lines = [f"{name}: accept {d['accept']}, kind margin {d['kind_margin']}, weights "
             f"{d['weights']}"]  # fmt: skip
    for scope, f in r["held-out"].items():
        if scope == "recorded":
            lines.append(f"  recorded (real): unrelated {f['unrelated']}")
            continue
        worst = ", ".join(f"{t} {s[0]}" for t, s in f["worst words"].items())
        cond = ", ".join(f"{c} {s[0]}" for c, s in f["conditions"].items())
        lines.append(
            f"  {scope}: clean {f['clean']}, near {f['near']}, unrelated {f['unrelated']}, "
            f"other kind {f['other kind']['heard']}/{f['other kind']['n']}, rtf {f['rtf']}, "
            f"p95 {f['latency p95']}\n    worst: {worst}\n    conditions: {cond}"
        )
    t = r["tune"]
    lines.append(f"  tune: clean {t['clean']}, near {t['near']}, unrelated {t['unrelated']}, "
                 f"other kind {t['other kind']['heard']}/{t['other kind']['n']}")  # fmt: skip
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())

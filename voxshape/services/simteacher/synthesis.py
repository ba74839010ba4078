"""Speech synthesis for simulated teachers: phrases spoken by espeak-ng, as 16 kHz mono int16
samples with silence around (sox trims, normalizes and pads them)."""

from __future__ import annotations

import io
import shutil
import subprocess
import wave

import numpy as np

from voxshape.protocol.messages import SAMPLE_RATE
from voxshape.runtime import ConfigError

LEAD_S, TRAIL_S = 0.3, 0.5  # silence before (the onset is at its end) and after the speech
VOICE = "en-us"


class Voice:
    """Phrases synthesized by espeak-ng, as 16 kHz mono int16 samples with silence around."""

    def __init__(self, voice: str = VOICE) -> None:
        missing = [tool for tool in ("espeak-ng", "sox") if shutil.which(tool) is None]
        if missing:
            raise ConfigError(
                f"--audio needs {' and '.join(missing)} (Debian: apt-get install espeak-ng sox); "
                "without them, run the speech service's mock engine and leave out --audio"
            )
        self.voice = voice
        self._cache: dict[str, np.ndarray] = {}

    def __call__(self, text: str) -> np.ndarray:
        if text not in self._cache:
            self._cache[text] = synthesize(text, self.voice)
        return self._cache[text]


def synthesize(text: str, voice: str = VOICE) -> np.ndarray:
    """`text` spoken by espeak-ng, trimmed, normalized and padded (LEAD_S, TRAIL_S) by sox."""
    speech = _run(["espeak-ng", "-v", voice, "-s", "150", "--stdout", text])
    trim = ["silence", "1", "0.01", "0.1%", "reverse", "silence", "1", "0.01", "0.1%", "reverse"]
    fmt = ["-r", str(SAMPLE_RATE), "-c", "1", "-b", "16", "-e", "signed-integer"]
    pad = ["pad", f"{LEAD_S}", f"{TRAIL_S}"]
    wav = _run(
        ["sox", "-R", "-t", "wav", "-", *fmt, "-t", "wav", "-", *trim, "gain", "-n", "-3", *pad],
        speech,
    )
    with wave.open(io.BytesIO(wav)) as w:
        return np.frombuffer(w.readframes(w.getnframes()), dtype="<i2")


def _run(argv: list[str], stdin: bytes | None = None) -> bytes:
    try:
        return subprocess.run(argv, input=stdin, capture_output=True, check=True, timeout=30).stdout
    except (subprocess.CalledProcessError, subprocess.TimeoutExpired) as e:
        raise ConfigError(f"{argv[0]} failed: {getattr(e, 'stderr', b'') or e}") from None

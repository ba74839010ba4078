"""PCM and WAV helpers: everything on the bus is 16 kHz mono signed 16-bit little-endian."""

from __future__ import annotations

import wave
from pathlib import Path

import numpy as np

from voxshape.protocol.messages import SAMPLE_RATE

FRAME_SAMPLES = SAMPLE_RATE // 100  # 10 ms


class AudioError(ValueError):
    """Audio that cannot be used; the message names the problem and the fix."""


def pcm_to_samples(pcm: bytes) -> np.ndarray:
    """int16 samples of little-endian PCM bytes; raises AudioError on an odd byte count."""
    if len(pcm) % 2:
        raise AudioError(f"{len(pcm)} bytes of PCM is an odd count: int16 samples are 2 bytes")
    return np.frombuffer(pcm, dtype="<i2").astype(np.int16)


def samples_to_pcm(samples: np.ndarray) -> bytes:
    return np.asarray(samples, dtype="<i2").tobytes()


def read_wav(path: str | Path) -> np.ndarray:
    """The samples of a 16 kHz mono 16-bit WAV file; anything else is an AudioError that says
    how to convert it."""
    path = Path(path)
    convert = f"convert it with: sox {path} -r 16000 -c 1 -b 16 -e signed-integer out.wav"
    try:
        with wave.open(str(path), "rb") as w:
            rate, channels, width = w.getframerate(), w.getnchannels(), w.getsampwidth()
            frames = w.readframes(w.getnframes())
    except FileNotFoundError:
        raise AudioError(f"{path}: no such WAV file") from None
    except (wave.Error, EOFError) as e:
        raise AudioError(f"{path}: not a PCM WAV file ({e}); {convert}") from None
    if (rate, channels, width) != (SAMPLE_RATE, 1, 2):
        raise AudioError(
            f"{path}: {rate} Hz, {channels} channel(s), {8 * width}-bit; voxshape needs "
            f"{SAMPLE_RATE} Hz mono 16-bit: {convert}"
        )
    return pcm_to_samples(frames)


def level_dbfs(samples: np.ndarray) -> float:
    """RMS level in dB relative to full scale; digital silence is -100."""
    if len(samples) == 0:
        return -100.0
    x = samples.astype(np.float64) / 32768.0
    power = float(np.mean(x * x))
    return max(-100.0, 10.0 * np.log10(power)) if power > 0 else -100.0


def chunks(samples: np.ndarray, chunk_samples: int) -> list[np.ndarray]:
    """`samples` cut into consecutive pieces of `chunk_samples` (the last may be shorter)."""
    return [samples[i : i + chunk_samples] for i in range(0, len(samples), chunk_samples)]

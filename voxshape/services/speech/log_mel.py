"""Whisper's input: the log-Mel spectrogram of 16 kHz audio, as openai/whisper computes it
(`audio.log_mel_spectrogram`): a 25 ms Hann window every 10 ms, Slaney-scaled Mel filters,
log10 of the power clipped 8 decades below its peak, then scaled to about [-1, 1]."""

from __future__ import annotations

from functools import cache

import numpy as np

from voxshape.protocol.messages import SAMPLE_RATE

N_FFT, HOP = 400, 160  # samples: 25 ms windows, 10 ms apart


def log_mel(audio: np.ndarray, n_mels: int = 80) -> np.ndarray:
    """(n_mels, frames) for float audio in [-1, 1]: one frame per 10 ms of it."""
    audio = np.pad(np.asarray(audio, dtype=np.float32), (0, HOP))  # as faster-whisper pads
    padded = np.pad(audio, N_FFT // 2, mode="reflect")  # frames centred on their samples
    frames = 1 + (len(padded) - N_FFT) // HOP
    windows = np.lib.stride_tricks.sliding_window_view(padded, N_FFT)[::HOP][:frames]
    spectrum = np.fft.rfft(windows * np.hanning(N_FFT + 1)[:-1].astype(np.float32), axis=-1)
    power = (np.abs(spectrum.astype(np.complex64)) ** 2).T[:, :-1]  # the last frame dropped
    mel = mel_filters(n_mels) @ power
    log_spec = np.log10(np.maximum(mel, 1e-10))
    log_spec = np.maximum(log_spec, log_spec.max() - 8.0)
    return (log_spec + 4.0) / 4.0


@cache  # the same few filters for every utterance
def mel_filters(n_mels: int) -> np.ndarray:
    """(n_mels, N_FFT // 2 + 1) triangular filters on the Slaney Mel scale (linear below
    1 kHz, logarithmic above), each normalized to constant energy, as librosa's `mel`."""
    bins = np.fft.rfftfreq(N_FFT, 1.0 / SAMPLE_RATE)
    mels = np.linspace(0.0, 45.245640471924965, n_mels + 2)  # 0 Hz to 8 kHz, in Mels
    hz = 200.0 / 3 * mels
    log_region = mels >= 15.0  # 1 kHz
    hz[log_region] = 1000.0 * np.exp(np.log(6.4) / 27.0 * (mels[log_region] - 15.0))
    ramps = hz[:, None] - bins[None, :]
    widths = np.diff(hz)
    lower = -ramps[:-2] / widths[:-1, None]
    upper = ramps[2:] / widths[1:, None]
    weights = np.maximum(0.0, np.minimum(lower, upper))
    return (weights * (2.0 / (hz[2:] - hz[:-2]))[:, None]).astype(np.float32)

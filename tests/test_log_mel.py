"""voxshape/services/speech/log_mel.py (Whisper's input) against an independent implementation:
librosa's STFT and Slaney Mel filters, whose values tests/fixtures/speech/
make_log_mel_reference.py made (the command is in its docstring). A wrong window, padding,
hop, Mel scale or filter normalization is off by 0.02 to 0.6, or a frame, where these agree
to 1e-6."""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import ROOT
from voxshape.services.speech.log_mel import log_mel, mel_filters

REFERENCE = ROOT / "tests" / "fixtures" / "speech" / "log_mel_reference.npz"


@pytest.fixture(scope="module")
def reference():
    with np.load(REFERENCE) as saved:
        return dict(saved)


@pytest.mark.parametrize("n_mels", [80, 128])  # tiny.en's, and large-v3's
def test_the_mel_filters_are_librosas(reference, n_mels):
    expected = reference[f"filters_{n_mels}"]
    assert mel_filters(n_mels).shape == expected.shape == (n_mels, 201)
    np.testing.assert_allclose(mel_filters(n_mels), expected, rtol=0, atol=1e-7)


@pytest.mark.parametrize("n_mels", [80, 128])
def test_the_log_mel_spectrogram_is_librosas_with_whispers_scaling(reference, n_mels):
    audio = reference["audio"]
    expected = reference[f"log_mel_{n_mels}"]
    got = log_mel(audio, n_mels)
    assert got.shape == expected.shape == (n_mels, 1 + len(audio) // 160)  # a frame per hop
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-4)

"""STFT/iSTFT with AV-NeRF's settings: shapes, perfect reconstruction, batching, any length."""

import numpy as np
import pytest
import torch

from avgs import dsp
from avgs.config import STFT


def test_one_second_clip_gives_257_by_173():
    x = torch.randn(STFT.sample_rate)
    spec = dsp.stft(x)
    assert spec.shape == (257, 173)
    assert spec.is_complex()


@pytest.mark.parametrize("length", [1, 7, 100, 255, 256, 257, 511, 512, 513, 22050, 22050 * 3 + 17])
def test_istft_inverts_stft_for_any_length(length):
    gen = torch.Generator().manual_seed(length)
    x = torch.randn(2, length, generator=gen)
    y = dsp.istft(dsp.stft(x), length=length)
    assert y.shape == x.shape
    torch.testing.assert_close(y, x, atol=2e-6 * max(1.0, float(x.abs().max())), rtol=0)


def test_batched_equals_one_by_one():
    x = torch.randn(3, 2, 4000)
    batched = dsp.stft(x)
    for i in range(3):
        for c in range(2):
            torch.testing.assert_close(batched[i, c], dsp.stft(x[i, c]))


def test_pure_tone_peaks_at_its_bin():
    sr = STFT.sample_rate
    k = 40  # bin index
    f = k * sr / STFT.n_fft
    t = np.arange(sr) / sr
    mag = dsp.magnitude(np.sin(2 * np.pi * f * t).astype(np.float32))
    assert int(mag[:, 20:-20].mean(dim=1).argmax()) == k
    # Hann window, amplitude 1: the peak is sum(window) / 2.
    expected = float(torch.hann_window(STFT.win_length).sum()) / 2
    assert float(mag[k, 20:-20].mean()) == pytest.approx(expected, rel=1e-3)


def test_numpy_input_and_frame_count():
    x = np.zeros(1000, dtype=np.float32)
    assert dsp.stft(x).shape[-1] == dsp.n_frames(1000) == 1 + 1000 // STFT.hop_length


def test_window_cached_under_inference_mode_still_works_with_autograd():
    dsp.window.cache_clear()
    with torch.inference_mode():
        dsp.stft(torch.randn(1000))  # first use caches the window
    x = torch.randn(1000, requires_grad=True)
    dsp.stft(x).abs().sum().backward()
    assert torch.isfinite(x.grad).all()

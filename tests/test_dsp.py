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
    dsp._window.cache_clear()
    with torch.inference_mode():
        dsp.stft(torch.randn(1000))  # first use caches the window
    x = torch.randn(1000, requires_grad=True)
    dsp.stft(x).abs().sum().backward()
    assert torch.isfinite(x.grad).all()


def _inconsistency(y: torch.Tensor, target: torch.Tensor) -> float:
    return float(torch.linalg.vector_norm(dsp.magnitude(y) - target) / torch.linalg.vector_norm(target))


def test_griffin_lim_keeps_a_consistent_spectrogram():
    """A true STFT is a fixed point: its own magnitudes and phase give the signal back."""
    x = torch.from_numpy(np.random.default_rng(0).standard_normal((2, 7000)).astype(np.float32))
    spec = dsp.stft(x)
    y = dsp.griffin_lim(spec, spec.abs(), 7000, iterations=8)
    assert torch.allclose(y, x, atol=1e-4)


def test_griffin_lim_brings_the_waveform_to_the_target_magnitudes():
    """Magnitudes reshaped in time (not a consistent STFT) with the original phase: each
    round of iterations brings the waveform's own magnitudes closer to the target."""
    x = torch.from_numpy(np.random.default_rng(1).standard_normal(22050).astype(np.float32))
    spec = dsp.stft(x)
    n = spec.shape[-1]
    target = spec.abs() * (1.0 + 0.8 * torch.sin(torch.arange(n) / 3.0))  # [F, N], a tremolo of 6 frames
    start = target * spec / spec.abs()
    errors = [_inconsistency(dsp.griffin_lim(start, target, 22050, k), target) for k in (0, 2, 8, 32)]
    assert errors[0] > 0.05  # the plain iSTFT is 6-7 % off its target here
    assert errors[0] > errors[1] > errors[2] > errors[3]
    assert errors[2] < 0.85 * errors[0]
    plain = [_inconsistency(dsp.griffin_lim(start, target, 22050, 8, momentum=m), target) for m in (0.0, 0.99)]
    assert plain[1] < plain[0]  # momentum (fast Griffin-Lim) converges faster


@pytest.mark.parametrize("length", [300 * 128, 66167])
def test_griffin_lim_in_blocks_equals_one_pass(length):
    """Blocks with a margin of the iterations' reach give the one-pass waveform."""
    x = torch.from_numpy(np.random.default_rng(2).standard_normal((2, length)).astype(np.float32))
    spec = dsp.stft(x)
    target = spec.abs() * torch.linspace(0.2, 1.5, spec.shape[-2])[:, None]
    start = target * torch.exp(1j * torch.from_numpy(np.random.default_rng(3).uniform(0, 6, spec.shape)).float())
    one = dsp.griffin_lim(start, target, length, 8, block_frames=10**9)
    for block in (16, 70):
        blocked = dsp.griffin_lim(start, target, length, 8, block_frames=block)
        assert torch.allclose(blocked, one, atol=1e-5 * float(one.abs().max()))
    assert torch.equal(dsp.griffin_lim(start, target, length, 0), dsp.istft(start, length))


def test_griffin_lim_rejects_bad_settings():
    spec = dsp.stft(torch.zeros(1000))
    for iterations, momentum in ((-1, 0.5), (4, 1.0), (4, -0.1)):
        with pytest.raises(ValueError, match="iterations >= 0 and momentum in"):
            dsp.griffin_lim(spec, spec.abs(), 1000, iterations, momentum)

"""The reverberant tail of B (:mod:`avgs.acoustics.reverb_tail`) against known signals."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from avgs import dsp
from avgs.acoustics.reverb_tail import BLOCK_FRAMES, ReverbTail, decay_per_frame, tail_power, tail_power_recursive
from avgs.acoustics.synthesis import Masks, binaural_waveform, ear_magnitudes
from avgs.config import STFT, TrainConfig


HOP_S = STFT.hop_length / STFT.sample_rate


def brute_force(mag: np.ndarray, decay: np.ndarray) -> np.ndarray:
    """The defining double sum, float64: P[f, t] = sum_{k=1..t} decay_f^k mag[f, t-k]^2."""
    F, N = mag.shape
    out = np.zeros((F, N))
    for t in range(N):
        for k in range(1, t + 1):
            out[:, t] += decay**k * mag[:, t - k] ** 2
    return out


def test_tail_power_fft_and_recursion_equal_the_defining_sum():
    rng = np.random.default_rng(0)
    mag = rng.random((5, 40)) * 3
    decay = np.array([0.0001, 0.3, 0.8, 0.95, 0.999])
    ref = brute_force(mag, decay)
    fft = tail_power(torch.from_numpy(mag), torch.from_numpy(decay)).numpy()
    rec, _ = tail_power_recursive(torch.from_numpy(mag), torch.from_numpy(decay))
    assert np.allclose(fft, ref, rtol=1e-9, atol=1e-9)
    assert np.allclose(rec.numpy(), ref, rtol=1e-12, atol=1e-12)


def test_tail_power_of_long_inputs_is_exact_block_by_block():
    """Past BLOCK_FRAMES the convolution runs block by block; the recursion is the reference."""
    g = torch.Generator().manual_seed(1)
    n = 2 * BLOCK_FRAMES + 357
    mag = torch.rand(2, 7, n, generator=g, dtype=torch.float64)  # batch of 2
    decay = decay_per_frame(torch.tensor([0.05, 0.3, 0.6, 1.0, 2.0, 4.0, 8.0], dtype=torch.float64), HOP_S)
    rec, _ = tail_power_recursive(mag, decay)
    assert torch.allclose(tail_power(mag, decay), rec, rtol=1e-9, atol=1e-9)


def test_an_impulse_decays_by_60_db_in_rt60():
    """One frame of unit power at t0: the tail is silent before, then falls 60 dB per RT60."""
    rt60 = 0.5
    steps = 50  # frames in which the power must fall by 10^(-6 * 50 hop / rt60)
    mag = torch.zeros(1, 300, dtype=torch.float64)
    mag[0, 100] = 1.0
    p = tail_power(mag, decay_per_frame(torch.tensor([rt60], dtype=torch.float64), HOP_S))[0]
    assert torch.all(p[:101] < 1e-12)  # causal (but FFT rounding)
    assert p[101].item() == pytest.approx(10 ** (-6 * HOP_S / rt60), rel=1e-9)
    assert (p[101 + steps] / p[101]).item() == pytest.approx(10 ** (-6 * steps * HOP_S / rt60), rel=1e-9)
    # the level falls by 60 dB over RT60 seconds
    frames_rt60 = rt60 / HOP_S
    level = 10 * math.log10(p[101 + 60].item() / p[101].item())
    assert level == pytest.approx(-60 * 60 / frames_rt60, rel=1e-9)


def test_zero_reverberant_gain_is_the_paper_mask_model():
    g = torch.Generator().manual_seed(2)
    mag = torch.rand(3, 257, 20, generator=g)
    mixture, difference = torch.rand(3, 257, generator=g), torch.rand(3, 257, generator=g) * 2 - 1
    ours = ear_magnitudes(mag, Masks(mixture, difference, torch.zeros(3, 2, 257), torch.full((257,), 0.9)))
    s_m = mag * mixture[..., None]
    paper = (s_m, s_m + s_m * difference[..., None], s_m - s_m * difference[..., None])  # the paper's formulas
    for a, b in zip(ours, paper):
        assert torch.allclose(a, b, atol=1e-6)


def test_the_tail_fills_the_silence_after_a_burst():
    """A noise burst then silence: the mask model is silent after the burst, the tail rings
    on and dies away at the rate its RT60 says."""
    sr = STFT.sample_rate
    x = torch.zeros(sr)
    x[: sr // 4] = torch.randn(sr // 4, generator=torch.Generator().manual_seed(3))
    spec = dsp.stft(x[None])  # [1, F, N]
    ones, zeros = torch.ones(1, 257), torch.zeros(1, 257)
    rt60 = torch.full((257,), 0.4)
    dry = binaural_waveform(spec, Masks(ones, zeros), sr)[0]
    wet = binaural_waveform(spec, Masks(ones, zeros, torch.full((1, 2, 257), 0.3), decay_per_frame(rt60, HOP_S)), sr)[0]

    def level(y, t0, t1):  # dB of the mean power in [t0, t1) seconds
        seg = y[:, int(t0 * sr) : int(t1 * sr)]
        return 10 * math.log10(float(seg.square().mean()) + 1e-30)

    assert level(dry, 0.35, 0.45) < -100  # nothing after the burst (but STFT leakage)
    first, second = level(wet, 0.30, 0.40), level(wet, 0.50, 0.60)
    assert first > level(wet, 0.0, 0.25) - 30  # audible ringing
    assert second - first == pytest.approx(-60 * 0.2 / 0.4, abs=4.0)  # 60 dB per RT60 (STFT-smoothed)


def test_rt60_and_gains_are_learned_from_a_known_decay():
    """Targets made by the model itself with RT60 = 0.3 s: fitting recovers it from 0.5 s."""
    g = torch.Generator().manual_seed(4)
    F, N = 8, 120
    mag = (torch.rand(16, F, N, generator=g) > 0.7).float() * torch.rand(16, F, N, generator=g)  # sparse bursts
    true_power = tail_power(mag, decay_per_frame(torch.full((F,), 0.3), HOP_S))
    gains = torch.full((16, 2, F), 0.5)
    mixture, difference = torch.full((16, F), 0.8), torch.zeros(16, F)
    _, t_l, t_r = ear_magnitudes(mag, Masks(mixture, difference, gains, torch.ones(F)), true_power)

    tail = ReverbTail(F, width=4, hop_seconds=HOP_S, init_rt60=0.5)
    features = torch.zeros(16, F, 4)
    opt = torch.optim.Adam(tail.parameters(), lr=0.05)
    for _ in range(300):
        _, s_l, s_r = ear_magnitudes(mag, Masks(mixture, difference, tail.gains(features), tail.decay()))
        loss = (s_l - t_l).square().mean() + (s_r - t_r).square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert torch.allclose(tail.rt60(), torch.full((F,), 0.3), rtol=0.05)
    assert torch.allclose(tail.gains(features), gains, rtol=0.05)


# -- the renderer ------------------------------------------------------------------------------


def test_renderer_reports_the_tail(tail_renderer):
    assert tail_renderer.rt60 == pytest.approx(np.linspace(0.2, 0.8, 257), rel=1e-5)
    a = tail_renderer.masks((1.0, 1.0, 1.6), 0.0).reverb
    b = tail_renderer.masks((5.0, 3.0, 1.6), 120.0).reverb
    assert a.shape == (2, 257) and np.all(a >= 0) and not np.allclose(a, b)


@pytest.mark.parametrize("length", [1, 300, 22050, 3 * 22050 + 17])
def test_streamed_tail_equals_the_one_shot_render(tail_renderer, length):
    x = np.random.default_rng(length).standard_normal(length).astype(np.float32) * 0.2
    one_shot = tail_renderer.render((2.0, 1.0, 1.6), 45.0, x).binaural
    stream = tail_renderer.stream((2.0, 1.0, 1.6), 45.0)
    sizes = np.random.default_rng(1).integers(1, 3000, size=200)
    bounds = np.unique(np.minimum(np.concatenate([[0], np.cumsum(sizes), [length]]), length))
    y = np.concatenate([stream.process(x[a:b]) for a, b in zip(bounds[:-1], bounds[1:])] + [stream.flush()], axis=1)
    assert y.shape == one_shot.shape
    assert np.max(np.abs(y - one_shot)) <= 1e-4 * max(1.0, float(np.max(np.abs(one_shot))))


def test_checkpoints_from_before_the_tail_load_as_the_mask_model():
    stored = TrainConfig().to_dict()
    del stored["acoustic"]["reverb_tail"]  # as written before the tail existed
    assert TrainConfig.from_dict(stored).acoustic.reverb_tail is False
    assert TrainConfig.from_dict(TrainConfig().to_dict()).acoustic.reverb_tail is True


def test_checkpoints_from_before_the_listener_encoding_option_keep_ten_frequencies():
    stored = TrainConfig().to_dict()
    del stored["acoustic"]["position_frequencies"]  # as written before the option existed
    assert TrainConfig.from_dict(stored).acoustic.position_frequencies == 10

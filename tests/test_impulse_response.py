"""A pose as a filter: the impulse response of B's masks, and block convolution with it.

Known signals against known numbers: a minimum-phase filter has the masks' magnitude, the
tail's energy and decay are the mask model's, white noise through the whole filter has the
mask model's expected ear power, and block convolution equals one FFT convolution.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from avgs import dsp
from avgs.acoustics.convolution import ConvolutionStream, BlockConvolver
from avgs.acoustics.impulse_response import TailShaper, convolve, impulse_response, minimum_phase, tail_frames
from avgs.acoustics.reverb_tail import decay_per_frame
from avgs.acoustics.synthesis import Masks, ear_magnitudes
from avgs.config import STFT

F = STFT.n_freq
HOP_S = STFT.hop_length / STFT.sample_rate


def smooth_gains(seed: int, batch: int = 3) -> torch.Tensor:
    """Random smooth gains [batch, F] between about -20 and +6 dB."""
    g = torch.Generator().manual_seed(seed)
    knots = torch.rand(batch, 1, 12, generator=g, dtype=torch.float64) * 26.0 - 20.0
    db = torch.nn.functional.interpolate(knots, size=F, mode="linear", align_corners=True)[:, 0]
    return 10.0 ** (db / 20.0)


def test_minimum_phase_filter_has_the_gains_as_its_magnitude():
    gains = smooth_gains(0)
    h = minimum_phase(gains, STFT.n_fft)  # [3, n_fft]
    response = torch.fft.rfft(h, STFT.n_fft).abs()
    assert torch.allclose(response, gains, rtol=0.03)
    # minimum phase: most of the energy comes first (a linear-phase filter would centre it at n_fft / 2)
    energy = h.square().cumsum(-1) / h.square().sum(-1, keepdim=True)
    assert bool((energy[:, 64] > 0.9).all())


def test_minimum_phase_of_silence_is_silence_and_of_a_flat_gain_an_impulse():
    assert torch.equal(minimum_phase(torch.zeros(2, F, dtype=torch.float64), STFT.n_fft), torch.zeros(2, STFT.n_fft, dtype=torch.float64))
    h = minimum_phase(torch.full((1, F), 0.5, dtype=torch.float64), STFT.n_fft)[0]
    assert h[0] == pytest.approx(0.5, abs=1e-9) and float(h[1:].abs().max()) < 1e-9


def tail_masks(rt60: torch.Tensor, reverb: torch.Tensor, mixture=None) -> Masks:
    mixture = torch.zeros(reverb.shape[0], F, dtype=torch.float64) if mixture is None else mixture
    return Masks(mixture, torch.zeros_like(mixture), reverb, decay_per_frame(rt60, HOP_S))


def test_tail_energy_per_bin_is_the_mask_models_and_decays_at_its_rt60():
    rt60 = torch.linspace(0.3, 0.9, F, dtype=torch.float64)
    masks = tail_masks(rt60, torch.full((1, 2, F), 0.5, dtype=torch.float64))
    shaper = TailShaper(masks.decay)
    tail = shaper(masks.reverb)[0]  # [2, L]
    w = masks.decay
    frames = dsp.stft(tail, STFT).abs().square()  # [2, F, K]
    energy = frames.sum(-1) * STFT.hop_length / dsp.window(STFT.win_length, "cpu", torch.float64).square().sum()
    expected = 0.25 * w / (1 - w)  # r^2 w / (1 - w)
    ratio = energy / expected
    assert float(ratio.median()) == pytest.approx(1.0, rel=0.05)
    assert float(ratio.quantile(0.05)) > 0.7 and float(ratio.quantile(0.95)) < 1.35  # one draw of noise, not its mean
    # the decay rate: a line fitted to the log energy of frames 5 .. 80, both ears and 11 bins around f
    k = torch.arange(5, 81, dtype=torch.float64)
    for f in (20, 100, 200):
        level = 10 * torch.log10(frames[:, f - 5 : f + 6, 5:81].mean((0, 1)))
        slope = float(((k - k.mean()) * (level - level.mean())).sum() / ((k - k.mean()) ** 2).sum())  # dB per frame
        assert -60.0 / slope * HOP_S == pytest.approx(float(rt60[f]), rel=0.2)


def test_white_noise_through_the_filter_has_the_mask_models_expected_power():
    g = torch.Generator().manual_seed(3)
    mixture = smooth_gains(4, batch=1)  # masks as B makes them: smooth over frequency
    difference = torch.tanh(torch.log(smooth_gains(5, batch=1)) * 0.3)
    reverb = 0.3 * smooth_gains(6, batch=2)[None]  # [1, 2, F]
    masks = Masks(mixture, difference, reverb, decay_per_frame(torch.full((F,), 0.5, dtype=torch.float64), HOP_S))
    x = torch.randn(STFT.sample_rate * 8, generator=g, dtype=torch.float64)
    y = convolve(x, impulse_response(masks)[0])  # [2, T]
    got = dsp.stft(y, STFT).abs().square()[..., 40:].mean(-1)  # [2, F], past the tail's build-up
    _, s_l, s_r = ear_magnitudes(dsp.stft(x, STFT).abs()[None], masks)
    want = torch.stack([s_l[0], s_r[0]]).square()[..., 40:].mean(-1)
    band = torch.ones(1, 1, 9, dtype=torch.float64) / 9  # one draw of noise: its energy holds over bands of bins
    ratio = torch.nn.functional.conv1d(got[:, None], band)[:, 0] / torch.nn.functional.conv1d(want[:, None], band)[:, 0]
    assert float(ratio.median()) == pytest.approx(1.0, rel=0.05)
    assert float((ratio - 1).abs().quantile(0.9)) < 0.25


def test_the_tail_is_cut_where_it_has_decayed_and_the_filter_is_deterministic():
    rt60 = torch.full((F,), 0.5, dtype=torch.float64)
    w = decay_per_frame(rt60, HOP_S)
    k = tail_frames(w, HOP_S)
    assert float(w[0]) ** (k - 1) < 1e-7 <= float(w[0]) ** (k - 2)  # 70 dB down, no further
    masks = tail_masks(rt60, torch.full((1, 2, F), 0.2, dtype=torch.float64), smooth_gains(5, batch=1))
    assert torch.equal(impulse_response(masks), impulse_response(masks))
    assert impulse_response(masks).shape[-1] == (k - 1) * STFT.hop_length


def test_block_convolution_equals_one_fft_convolution():
    rng = np.random.default_rng(0)
    h = (rng.standard_normal((2, 3000)) * np.exp(-np.arange(3000) / 500)).astype(np.float32)
    x = rng.standard_normal(10_000).astype(np.float32)
    ref = convolve(torch.from_numpy(x).double(), torch.from_numpy(h).double()).numpy()
    c = BlockConvolver(h, 256)
    xs = np.pad(x, (0, (-x.size) % 256))
    y = np.concatenate([c.process(xs[i : i + 256]) for i in range(0, xs.size, 256)], axis=1)[:, : x.size]
    assert np.max(np.abs(y - ref)) < 1e-5 * np.max(np.abs(ref))
    s = ConvolutionStream(h, 128)
    sizes = rng.integers(1, 700, 60)
    bounds = np.unique(np.minimum(np.concatenate([[0], np.cumsum(sizes), [x.size]]), x.size))
    y2 = np.concatenate([s.process(x[a:b]) for a, b in zip(bounds[:-1], bounds[1:])] + [s.flush()], axis=1)
    assert y2.shape == ref.shape and np.max(np.abs(y2 - ref)) < 1e-5 * np.max(np.abs(ref))


def test_a_new_response_is_crossfaded_over_one_block_then_used_alone():
    rng = np.random.default_rng(1)
    h1 = rng.standard_normal((2, 700)).astype(np.float32) * 0.1
    h2 = rng.standard_normal((2, 700)).astype(np.float32) * 0.1
    x = rng.standard_normal(64 * 40).astype(np.float32)
    y1 = convolve(torch.from_numpy(x).double(), torch.from_numpy(h1).double()).numpy()
    y2 = convolve(torch.from_numpy(x).double(), torch.from_numpy(h2).double()).numpy()
    c = BlockConvolver(h1, 64)
    out = []
    for i in range(40):
        if i == 20:
            c.set_impulse(h2)
        out.append(c.process(x[i * 64 : (i + 1) * 64]))
    y = np.concatenate(out, axis=1)
    assert np.allclose(y[:, : 20 * 64], y1[:, : 20 * 64], atol=1e-5)
    ramp = np.arange(1, 65, dtype=np.float64) / 64
    blend = y1[:, 20 * 64 : 21 * 64] * (1 - ramp) + y2[:, 20 * 64 : 21 * 64] * ramp
    assert np.allclose(y[:, 20 * 64 : 21 * 64], blend, atol=1e-5)
    assert np.allclose(y[:, 21 * 64 :], y2[:, 21 * 64 :], atol=1e-5)
    assert c.switches == 1
    c.set_impulse(rng.standard_normal((2, 1500)).astype(np.float32))  # longer: takes full effect once 1500 samples passed
    assert c.process(x[:64]).shape == (2, 64) and c.switches == 2


def test_renderer_filter_is_what_render_convolves(tmp_path):
    from avgs.io.checkpoint import untrained_checkpoint
    from avgs.config import SynthesisConfig
    from avgs.render.renderer import SceneRenderer

    g = torch.Generator().manual_seed(0)
    ckpt = untrained_checkpoint(torch.rand(400, 3, generator=g) * 2 - 1, torch.tensor([0.2, 0.1, 0.0]), seed=1)
    r = SceneRenderer(ckpt)
    x = np.random.default_rng(2).standard_normal(9000).astype(np.float32) * 0.3
    f = r.binaural_filter((0.1, 0.2, 0.0), 30.0)
    assert f.impulse.dtype == np.float32 and f.impulse.shape[0] == 2
    want = convolve(torch.from_numpy(x).double(), torch.from_numpy(f.impulse).double()).numpy()
    got = r.render((0.1, 0.2, 0.0), 30.0, x, synthesis=SynthesisConfig(method="filter")).binaural
    assert np.allclose(got, want, atol=1e-5 * np.max(np.abs(want)))
    spec = r.render((0.1, 0.2, 0.0), 30.0, x).binaural  # the default: predicted magnitudes with the filter's phase
    assert not np.allclose(got, spec, atol=1e-3)  # the two syntheses are different methods
    assert math.isclose(float(np.abs(got).max()), float(np.abs(spec).max()), rel_tol=0.5)  # of the same filter


def test_a_stream_moved_to_another_pose_settles_on_that_poses_output():
    from avgs.io.checkpoint import untrained_checkpoint
    from avgs.render.renderer import SceneRenderer

    g = torch.Generator().manual_seed(0)
    r = SceneRenderer(untrained_checkpoint(torch.rand(400, 3, generator=g) * 2 - 1, torch.tensor([0.2, 0.1, 0.0]), seed=1))
    x = np.random.default_rng(3).standard_normal(30_000).astype(np.float32) * 0.3
    a, b = ((0.1, 0.2, 0.0), 30.0), ((-0.5, 0.4, 0.0), 200.0)
    moved, fresh_a, fresh_b = r.stream(*a), r.stream(*a), r.stream(*b)
    out = {k: [] for k in ("moved", "a", "b")}
    for i in range(0, x.size, 1000):
        if i == 15_000:
            r.move_stream(moved, *b)
        for k, s in (("moved", moved), ("a", fresh_a), ("b", fresh_b)):
            out[k].append(s.process(x[i : i + 1000]))
    y = {k: np.concatenate(v, axis=1) for k, v in out.items()}
    n = y["moved"].shape[1]
    switch = 15_000 - moved.latency  # output before this was made before the move
    assert np.allclose(y["moved"][:, :switch], y["a"][:, :switch], atol=1e-6)
    settled = 15_000 + moved.latency + STFT.n_fft  # one block's crossfade and one window's overlap later
    assert np.allclose(y["moved"][:, settled:n], y["b"][:, settled:n], atol=1e-5)
    jump = np.abs(np.diff(y["moved"][:, switch - 1 : settled + 1], axis=1)).max()
    assert jump < 4 * np.abs(np.diff(y["b"], axis=1)).max()  # no click: no step larger than the signal's own

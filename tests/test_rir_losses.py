"""The impulse-response task's decay loss and the inverse-distance term, on known signals."""

from __future__ import annotations

import math

import pytest
import torch

from avgs.acoustics.rir_binauralizer import RIRBinauralizer
from avgs.config import STFT, RIRConfig, TrainConfig
from avgs.train.losses import DECAY_RANGE_DB, band_masks, decay_curves, decay_loss

HOP_S = STFT.hop_length / STFT.sample_rate
N = 120
"Frames of the test responses (0.7 s)."


def decaying_log_magnitude(rt60: float, level: float = 0.0, n_frames: int = N) -> torch.Tensor:
    """Log magnitudes [1, 2, F, N] of a response whose every bin decays by 60 dB in ``rt60`` seconds."""
    t = torch.arange(n_frames, dtype=torch.float64) * HOP_S
    per_frame = level - (3.0 * math.log(10.0) / rt60) * t  # log magnitude: 60 dB of power is 3 ln 10 nats of magnitude
    return per_frame.expand(1, 2, STFT.n_freq, n_frames).clone()


def test_band_masks_cover_every_bin_once_besides_the_whole_band():
    bands = band_masks(STFT.n_freq, STFT.sample_rate)
    assert bands.shape == (7, STFT.n_freq)  # whole band + 6 octave bands
    assert torch.equal(bands[0], torch.ones(STFT.n_freq))
    assert torch.equal(bands[1:].sum(0), torch.ones(STFT.n_freq))


def test_decay_curve_of_an_exponential_decay_is_its_line():
    rt60 = 0.5
    y = decaying_log_magnitude(rt60)
    curves = decay_curves(torch.exp(2.0 * y), band_masks(STFT.n_freq, STFT.sample_rate))  # [1, 2, K, N]
    t = torch.arange(N, dtype=torch.float64) * HOP_S
    rate = 6.0 * math.log(10.0) / rt60  # power, nats per second
    q = math.exp(-rate * HOP_S)
    exact = torch.log((q ** torch.arange(N, dtype=torch.float64) - q ** N) / (1.0 - q ** N))  # finite geometric tail, re its start
    within = exact > -DECAY_RANGE_DB / 10.0 * math.log(10.0)
    # exact but for the curve's floor, 80 dB down: at most ln(1 + 1e-3) at -50 dB
    assert torch.allclose(curves[0, 0, 0][within], exact[within], atol=2e-3)
    assert torch.allclose(curves[0, 1, 3][within], exact[within], atol=2e-3)  # every band decays alike
    # the straight line of the decay, -60 dB per rt60, until the end of the response bends it
    early = t < 0.3
    assert torch.allclose(curves[0, 0, 0][early], -rate * t[early], atol=0.05)


def test_decay_loss_is_zero_for_the_truth_and_pulls_a_short_decay_longer():
    bands = band_masks(STFT.n_freq, STFT.sample_rate)
    floor = -30.0
    truth = decaying_log_magnitude(0.6).float()
    assert float(decay_loss(truth, truth, bands, floor)) < 1e-6
    short = decaying_log_magnitude(0.4).float().requires_grad_(True)
    loss = decay_loss(short, truth, bands, floor)
    assert float(loss.detach()) > 1.0
    loss.backward()
    # the gradient raises the late frames against the early ones: a step down it lengthens the decay
    g = short.grad[0, 0].mean(0)  # [N]
    assert float(g[N // 2 :].mean()) < float(g[:5].mean())
    longer = decaying_log_magnitude(0.5).float()
    assert float(decay_loss(longer, truth, bands, floor)) < float(loss.detach())


def test_decay_loss_ignores_the_level():
    bands = band_masks(STFT.n_freq, STFT.sample_rate)
    truth = decaying_log_magnitude(0.6).float()
    louder = decaying_log_magnitude(0.6, level=2.0).float()
    assert float(decay_loss(louder, truth, bands, -30.0)) < 1e-4


def test_distance_term_follows_the_inverse_distance_law():
    """With the slope at 1 (the direct sound's law) and the network's head at zero, doubling
    the distance lowers every bin by exactly 20 log10 2 = 6.02 dB, at any distance."""
    net = RIRBinauralizer(RIRConfig(width=16, distance_slope=True, distance_knee=False), None, STFT.n_freq, 8, HOP_S)
    assert net.distance_slope is not None and torch.equal(net.distance_slope, torch.zeros(8))
    with torch.no_grad():
        net.distance_slope.fill_(1.0)
        net.log_distance_mean.fill_(math.log(2.0))
    listener = torch.zeros(4, 3)
    source = torch.tensor([[0.1, 0.0, 0.0], [0.2, 0.0, 0.0], [3.0, 0.0, 0.0], [6.0, 0.0, 0.0]])
    zeros = torch.zeros(4)
    with torch.no_grad():
        y = net(listener, source, zeros, zeros)  # [4, 2, F, 8]
    db = 20.0 / math.log(10.0)
    assert torch.allclose((y[0] - y[1]) * db, torch.full_like(y[0], 20.0 * math.log10(2.0)), atol=1e-4)
    assert torch.allclose((y[2] - y[3]) * db, torch.full_like(y[0], 20.0 * math.log10(2.0)), atol=1e-4)
    assert torch.allclose(y[0], torch.full_like(y[0], math.log(20.0)), atol=1e-5)  # 0.1 re the mean 2: +log 20


def test_knee_term_is_the_direct_plus_diffuse_law():
    """With the critical distance r and the head at zero, the level relative to the training
    pairs' mean distance is 10 log10((1 + r^2/d^2) / (1 + r^2/mean^2)) dB: 6 dB per doubling
    of d well inside r (the direct sound's 1/d), none well outside (the diffuse field)."""
    net = RIRBinauralizer(RIRConfig(width=16), None, STFT.n_freq, 8, HOP_S)  # the default
    assert net.distance_slope is None and torch.equal(net.log_critical, torch.full((8,), -2.0))
    mean, r = 2.0, 1.0
    with torch.no_grad():
        net.log_critical.fill_(math.log(r / mean))
        net.log_distance_mean.fill_(math.log(mean))
    d = torch.tensor([0.01, 0.02, 1.0, 2.0, 100.0, 200.0])
    listener, zeros = torch.zeros(6, 3), torch.zeros(6)
    source = torch.stack([d, torch.zeros(6), torch.zeros(6)], dim=-1)
    with torch.no_grad():
        y = net(listener, source, zeros, zeros)  # [6, 2, F, 8]
    db = 20.0 / math.log(10.0)
    want = 10.0 * torch.log10((1 + r ** 2 / d ** 2) / (1 + r ** 2 / mean ** 2))  # [6]
    assert torch.allclose(y * db, want[:, None, None, None].expand_as(y), atol=1e-4)
    assert float((y[0] - y[1]).mean() * db) == pytest.approx(20.0 * math.log10(2.0), abs=0.01)
    assert float((y[4] - y[5]).mean() * db) == pytest.approx(0.0, abs=0.01)


def test_checkpoints_from_before_the_distance_term_build_without_it():
    old = TrainConfig().to_dict()
    del old["rir"]["distance_slope"], old["rir"]["distance_knee"], old["rir"]["wall_loss"]
    cfg = TrainConfig.from_dict(old)
    assert cfg.rir.distance_slope is False and cfg.rir.distance_knee is False and cfg.rir.wall_loss is False
    assert TrainConfig().rir.distance_knee is True
    net = RIRBinauralizer(cfg.rir, None, STFT.n_freq, 8, HOP_S)
    assert net.distance_slope is None and net.log_critical is None
    new = RIRBinauralizer(TrainConfig().rir, None, STFT.n_freq, 8, HOP_S)
    with pytest.raises(RuntimeError, match="log_critical"):
        net.load_state_dict(new.state_dict())  # strict: a mismatch is an error, not a silent drop


def test_the_wall_term_adds_its_loss_per_wall_up_to_the_cap():
    """Each wall on the path adds ``wall_loss`` per frame to both ears and every bin; no wall (or no
    count) leaves the output as it is; more than WALL_MAX walls count as WALL_MAX."""
    from avgs.acoustics.rir_binauralizer import WALL_MAX

    net = RIRBinauralizer(RIRConfig(width=16), None, STFT.n_freq, 8, HOP_S)
    loss = -torch.linspace(0.1, 0.8, 8)
    with torch.no_grad():
        net.wall_loss.copy_(loss)
    listener, zeros = torch.zeros(4, 3), torch.zeros(4)
    source = torch.tensor([[1.0, 0.0, 0.0]]).expand(4, 3)
    walls = torch.tensor([0.0, 1.0, 2.5, 10.0])
    with torch.no_grad():
        plain = net(listener, source, zeros, zeros)
        with_walls = net(listener, source, zeros, zeros, walls=walls)
        some = net(listener, source, zeros, zeros, frames=torch.tensor([2, 5]), walls=walls)
    added = with_walls - plain  # [4, 2, F, 8]
    want = walls.clamp(max=WALL_MAX)[:, None] * loss  # [4, 8]
    assert torch.allclose(added, want[:, None, None, :].expand_as(added), atol=1e-6)
    assert torch.equal(added[0], torch.zeros_like(added[0]))
    assert torch.allclose(some, with_walls[..., [2, 5]], atol=1e-6)  # a subset of frames: the same numbers
    assert RIRBinauralizer(RIRConfig(width=16, wall_loss=False), None, STFT.n_freq, 8, HOP_S).wall_loss is None


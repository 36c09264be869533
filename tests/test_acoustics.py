"""Unit tests of the audio model's parts on small random tensors with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from avgs import dsp
from avgs.acoustics.binauralizer import Binauralizer
from avgs.data.frame import signed_direction
from avgs.acoustics.encodings import positional_encoding
from avgs.acoustics.field import AcousticField, unit_directions
from avgs.acoustics.model import AVGSModel
from avgs.acoustics.synthesis import Masks, binaural_waveform
from avgs.acoustics.points import AudioPoints, alpha_dim, alpha_from_colors, alpha_from_features, parse_alpha_spec
from avgs.acoustics.vicinity import nearest_indices, vicinity_size
from avgs.config import AcousticConfig, SynthesisConfig
from avgs.train.losses import magnitude_loss, volume_loss


def make_b(context_dim, **cfg) -> Binauralizer:
    return Binauralizer(AcousticConfig(**cfg), context_dim, n_freq=257, hop_seconds=128 / 22050)


def test_retired_direction_embedding_is_refused_by_name():
    from avgs.config import TrainConfig

    stored = TrainConfig().to_dict()
    stored["acoustic"]["direction_encoding"] = "embedding"
    with pytest.raises(ValueError, match="embedding.*no longer"):
        TrainConfig.from_dict(stored)


def test_positional_encoding_widths_and_values():
    xy = torch.tensor([[0.3, -0.5]])
    pe = positional_encoding(xy, 10)
    assert pe.shape == (1, 42)
    assert positional_encoding(torch.zeros(257, 1), 10).shape == (257, 21)
    # Layout: input, sin(2^k x) for k=0..9 (frequency-major), then cos; the top frequency is 2^9.
    assert torch.allclose(pe[0, :2], xy[0])
    assert torch.allclose(pe[0, 2:4], torch.sin(xy[0]))
    assert torch.allclose(pe[0, 20:22], torch.sin(512 * xy[0]))
    assert torch.allclose(pe[0, 22:24], torch.cos(xy[0]))


@pytest.mark.parametrize("n, p, k", [(100, 15, 15), (7, 15, 2), (1, 15, 1), (3, 100, 3), (1000, 0.01, 1)])
def test_vicinity_size(n, p, k):
    assert vicinity_size(n, p) == k


def test_vicinity_matches_brute_force():
    g = torch.Generator().manual_seed(1)
    pts = torch.rand(500, 3, generator=g) * 2 - 1
    q = torch.rand(6, 3, generator=g) * 2 - 1
    idx = nearest_indices(pts.T.contiguous(), q, 40)
    brute = np.argsort(((pts[None] - q[:, None]) ** 2).sum(-1).numpy(), axis=1)[:, :40]
    assert np.array_equal(np.sort(idx.numpy(), axis=1), np.sort(brute, axis=1))
    assert torch.equal(nearest_indices(pts.T.contiguous(), q[0], 40), idx[0])


@pytest.mark.parametrize("yaw_deg", [0.0, 37.0, 90.0, -140.0])
def test_theta_sign_left_and_right(yaw_deg):
    yaw = math.radians(yaw_deg)
    listener = torch.tensor([[0.1, -0.2, 0.0]])
    facing = np.array([math.cos(yaw), math.sin(yaw)])
    left = np.array([-facing[1], facing[0]])  # facing rotated +90 degrees (ccw)
    for side, sign in ((left, 1.0), (-left, -1.0)):
        src = listener[0].clone()
        src[:2] += torch.tensor(0.5 * side + 0.2 * facing, dtype=torch.float32)
        theta = signed_direction(listener, torch.tensor([yaw]), src)
        assert torch.sign(theta).item() == sign
        d = (src - listener[0])[:2].double().numpy()  # the source in the listener's own frame:
        ahead, leftward = d @ facing, d @ left  # rotate by -yaw
        assert theta.item() == pytest.approx(math.atan2(leftward, ahead), abs=1e-5)


def test_zero_distance_gives_finite_directions_and_gradients():
    X = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], requires_grad=True)
    origin = torch.zeros(1, 3)
    g = unit_directions(X[None], origin)  # [1, 2, 3]
    assert torch.equal(g[0, 0], torch.zeros(3))
    assert torch.allclose(g[0, 1], torch.tensor([1.0, 0.0, 0.0]))
    field = AcousticField(alpha_dim=4, width=8, layers=3, context_dim=5)
    c = field(X, torch.randn(2, 4), origin, torch.tensor([[0, 1]]))
    c.sum().backward()
    assert torch.isfinite(c).all() and torch.isfinite(X.grad).all()


def test_alpha_specs():
    assert parse_alpha_spec("sh+r") == ["sh", "r"]
    assert alpha_dim("sh+r") == 52 and alpha_dim("s+o") == 4
    for bad in ("", "sh+x", "r+r"):
        with pytest.raises(ValueError):
            parse_alpha_spec(bad)
    feats = {"sh": torch.randn(3, 48), "r": torch.tensor([[2.0, 0, 0, 0]] * 3)}
    a = alpha_from_features(feats, "r+sh")
    assert a.shape == (3, 52) and torch.allclose(a[:, :4], torch.tensor([[1.0, 0, 0, 0]] * 3))
    # SfM init: DC coefficient holds the colour, 0.5 grey maps to 0.
    assert torch.allclose(alpha_from_colors(torch.full((2, 3), 0.5), "sh")[:, :3], torch.zeros(2, 3))


def test_harmonic_direction_feature_is_periodic_and_lateral():
    b = make_b(None, binauralizer_width=8, direction_harmonics=3)
    theta = torch.tensor([0.5, 0.5 + 2 * math.pi, math.pi / 2, -math.pi / 2, math.pi, -math.pi])
    e = b.direction_feature(theta)  # [6, 6] = cos(n theta) (+) sin(n theta), n = 1..3
    assert e.shape == (6, 6) and b.direction_dim == 6 and b.diff_mlp[0].in_features == 8 + 6
    assert torch.allclose(e[0], e[1], atol=1e-5)  # one turn later, the same feature
    assert torch.allclose(e[4], e[5], atol=1e-5)  # continuous across the listener's back
    # sin(theta) is +1 with the source on the left, -1 on the right
    assert e[2, 3] == pytest.approx(1.0) and e[3, 3] == pytest.approx(-1.0)
    with pytest.raises(ValueError, match="direction_harmonics"):
        make_b(None, direction_harmonics=0)


@pytest.mark.parametrize("encoding", ["fourier", "harmonic"])
def test_direction_feature_reaches_every_difference_layer(encoding):
    """With the direction's weights in the first difference layer zeroed, theta still moves
    m_d when every layer takes the feature, and no longer moves it when only the first does."""
    xy, context = torch.rand(1, 2).expand(8, 2), torch.randn(1, 6).expand(8, 6)
    theta = torch.linspace(-3.0, 3.0, 8)
    swings = {}
    for every in (True, False):
        torch.manual_seed(0)
        b = make_b(6, binauralizer_width=16, direction_encoding=encoding, direction_every_layer=every)
        D = b.direction_dim
        widths = [layer.in_features for layer in b.diff_mlp]
        assert widths == ([16 + D] * 4 if every else [16 + D, 16, 16, 16])
        with torch.no_grad():
            b.diff_mlp[0].weight[:, 16:] = 0.0  # the first layer ignores theta
            m_d = b(xy, theta, context).difference  # [8, F]
        swings[every] = float((m_d.max(0).values - m_d.min(0).values).max())
    assert swings[True] > 1e-3
    assert swings[False] < 1e-6


def test_checkpoints_from_before_every_layer_directions_keep_the_first_layer_only():
    from avgs.config import TrainConfig

    stored = TrainConfig().to_dict()
    del stored["acoustic"]["direction_every_layer"]  # as written before the option existed
    assert TrainConfig.from_dict(stored).acoustic.direction_every_layer is False
    assert TrainConfig.from_dict(TrainConfig().to_dict()).acoustic.direction_every_layer is True


def test_the_bundled_demo_is_source_aware(capsys):
    """The demo is an impulse-response checkpoint: ``avgs info --json`` says so, and moving
    the source into the other room makes both ears quieter, as the simulator's truth does."""
    import json
    from pathlib import Path

    from avgs import SceneRenderer
    from avgs.cli import main

    demo = Path(__file__).resolve().parents[1] / "assets" / "demo" / "scene.ckpt"
    r = SceneRenderer.load(demo)
    assert r.source_aware and r.task == "rir"
    mono = np.random.default_rng(0).standard_normal(22050).astype(np.float32)
    listener = (2.0, 2.0, 1.6)
    near = r.render(listener, 0.0, mono, source=(3.0, 2.0, 1.5)).binaural
    other_room = r.render(listener, 0.0, mono, source=(7.5, 2.0, 1.5)).binaural
    level = lambda y: 10 * np.log10(np.mean(y.astype(np.float64) ** 2, axis=-1))  # noqa: E731
    assert np.all(level(near) - level(other_room) > 3.0)
    assert main(["info", str(demo), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["task"] == "rir" and 200 < info["itd_scale_us"] < 350  # the demo's head, fitted to its responses
    # B's wall term: the partition (x = 4.7 m, its door at 1.65 < y < 2.55) puts points on the path to a source
    # behind it, none on the path to one in the listener's room; with the term's learned levels zeroed the source
    # behind the wall comes out louder, the near one the same
    assert info["wall_unit_points"] < 1e11 and min(info["wall_loss_db"]) < -0.5
    at, here, behind = (2.0, 3.5, 1.6), (3.5, 3.5, 1.5), (7.0, 3.5, 1.5)
    model = r.model
    lis = torch.as_tensor(r.frame.to_normalised(np.array([at, at])), dtype=model.points.X.dtype)
    src = torch.as_tensor(r.frame.to_normalised(np.array([here, behind])), dtype=model.points.X.dtype)
    walls = model.walls(lis, src)
    assert float(walls[0]) == 0.0 and float(walls[1]) >= 1.0
    heard = [r.render(at, 0.0, mono, source=where).binaural for where in (here, behind)]
    with torch.no_grad():
        model.binauralizer.wall_loss.zero_()
    plain = [r.render(at, 0.0, mono, source=where).binaural for where in (here, behind)]
    assert np.allclose(level(plain[0]), level(heard[0]), atol=1e-3)
    assert np.all(level(plain[1]) - level(heard[1]) > 0.5)


@pytest.mark.parametrize("encoding", ["fourier", "harmonic"])
@pytest.mark.parametrize("activation", ["relu", "sigmoid"])
def test_binauralizer_mask_shapes_and_ranges(encoding, activation):
    torch.manual_seed(0)
    b = make_b(6, binauralizer_width=16, mixture_activation=activation, direction_encoding=encoding, reverb_tail=True)
    out = b(torch.rand(3, 2), torch.tensor([-3.1, 0.0, 3.1]), torch.randn(3, 6))
    m_m, m_d, r = out.mixture, out.difference, out.reverb
    assert m_m.shape == m_d.shape == (3, 257) and r.shape == (3, 2, 257)
    assert (m_m >= 0).all() and (m_d.abs() < 1).all() and (r >= 0).all()
    # every bin starts alive, at gain 0.5 (a dead relu bin would get no gradient)
    assert torch.allclose(m_m, torch.full_like(m_m, 0.5))
    if activation == "sigmoid":
        assert (m_m <= 1).all()
    assert b(torch.rand(3, 2), torch.zeros(3), torch.randn(3, 6)).reverb is not None
    plain = make_b(6, binauralizer_width=16, mixture_activation=activation, direction_encoding=encoding, reverb_tail=False)
    assert plain(torch.rand(3, 2), torch.zeros(3), torch.randn(3, 6)).reverb is None


def test_model_end_to_end_shapes_context_and_no_context():
    torch.manual_seed(0)
    pts = AudioPoints(torch.rand(200, 3) * 2 - 1, torch.randn(200, 52))
    model = AVGSModel(pts, AcousticConfig(binauralizer_width=32))
    assert model.vicinity_k == 30
    mag = torch.rand(2, 257, 9)
    (s_m, s_l, s_r), masks = model(torch.rand(2, 3), torch.tensor([0.3, -0.3]), torch.zeros(3), mag)
    assert s_m.shape == s_l.shape == (2, 257, 9)
    assert masks.listener_vicinity.shape == (2, 30) and masks.source_vicinity.shape == (30,)
    assert torch.allclose(s_l + s_r, 2 * s_m, atol=1e-6)
    # The context depends on the audio points: moving alpha changes the masks.
    with torch.no_grad():
        before = model.masks(torch.zeros(1, 3), torch.zeros(1), torch.ones(3)).difference.clone()
        model.points.alpha.add_(1.0)
        after = model.masks(torch.zeros(1, 3), torch.zeros(1), torch.ones(3)).difference
    assert not torch.allclose(before, after)
    # The control has no F and ignores the points entirely.
    ctl = AVGSModel(AudioPoints(torch.rand(50, 3), torch.randn(50, 52)), AcousticConfig(use_context=False))
    assert ctl.field is None
    assert ctl.masks(torch.zeros(1, 3), torch.zeros(1), torch.ones(3)).mixture.shape == (1, 257)


def test_binaural_waveform_with_unit_masks_returns_the_source():
    from avgs import dsp

    x = torch.randn(1, 3000)
    y = binaural_waveform(dsp.stft(x), Masks(torch.ones(1, 257), torch.zeros(1, 257)), 3000)
    assert y.shape == (1, 2, 3000)
    assert torch.allclose(y[0, 0], x[0], atol=1e-5) and torch.allclose(y[0, 1], x[0], atol=1e-5)
    # m_d = +0.5: left = 1.5 x, right = 0.5 x.
    y = binaural_waveform(dsp.stft(x), Masks(torch.ones(1, 257), torch.full((1, 257), 0.5)), 3000)
    assert torch.allclose(y[0, 0], 1.5 * x[0], atol=1e-4) and torch.allclose(y[0, 1], 0.5 * x[0], atol=1e-4)


def test_magnitude_loss_is_zero_on_the_truth():
    gt = torch.rand(2, 2, 257, 5)
    s_m, s_l, s_r = 0.5 * (gt[:, 0] + gt[:, 1]), gt[:, 0], gt[:, 1]
    assert magnitude_loss(s_m, s_l, s_r, gt).item() == 0.0
    assert magnitude_loss(s_m + 1.0, s_l, s_r, gt).item() == pytest.approx(1.0)


def test_volume_loss_equals_log1p_of_the_direct_product_where_finite():
    g = torch.Generator().manual_seed(0)
    alpha = (torch.rand(20, 6, generator=g, dtype=torch.float64) * 3 - 1.5)  # mixed signs
    direct = torch.log1p(alpha.prod(-1).abs()).sum()
    assert volume_loss(alpha).item() == pytest.approx(direct.item(), rel=1e-9)
    small = alpha * 1e-3  # where alpha lives the penalty is the paper's product itself
    assert volume_loss(small).item() == pytest.approx(small.prod(-1).abs().sum().item(), rel=1e-6)
    alpha32 = alpha.float().requires_grad_()
    volume_loss(alpha32).backward()
    alpha_ref = alpha.float().requires_grad_()
    torch.log1p(alpha_ref.prod(-1).abs()).sum().backward()
    assert torch.allclose(alpha32.grad, alpha_ref.grad, rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float16])
def test_volume_loss_stays_finite_where_the_direct_product_is_not(dtype):
    big = torch.full((4, 52), 30.0, dtype=dtype)  # 30^52 overflows both dtypes
    small = torch.full((4, 52), 1e-2, dtype=dtype)  # 1e-104 underflows to 0
    with_zero = torch.randn(4, 52).to(dtype)
    with_zero[:, 3] = 0
    assert not torch.isfinite(big.prod(-1).sum())
    for alpha in (big, small, with_zero):
        a = alpha.clone().requires_grad_()
        loss = volume_loss(a)
        loss.backward()
        assert torch.isfinite(loss) and torch.isfinite(a.grad).all()
    assert 0.0 <= volume_loss(small).item() < 1e-30  # the true value, 4e-104, rounds to 0 or a subnormal


def test_volume_loss_is_bounded_below_so_minimising_it_shrinks_alpha():
    # A signed product would be unbounded below (an odd number of negatives); |prod| is not.
    alpha = torch.full((3, 52), 1.5)
    alpha[:, 0] = -1.5
    alpha.requires_grad_()
    opt = torch.optim.SGD([alpha], lr=0.1)
    first = volume_loss(alpha).item()
    for _ in range(5):
        opt.zero_grad()
        loss = volume_loss(alpha)
        assert loss.item() >= 0.0
        loss.backward()
        opt.step()
    assert volume_loss(alpha).item() < first and alpha.detach().abs().max() <= 1.5


# -- AV-NeRF's time-frequency conv head (--post-conv) -----------------------------------


def test_post_conv_with_a_zero_residual_is_the_plain_mask_path():
    from avgs.acoustics.post_conv import PostConv

    torch.manual_seed(0)
    x = torch.randn(2, 9000)
    x[1, 3000:4000] = 0.0  # silent bins: the source phase is undefined there
    spec = dsp.stft(x)  # [2, F, N]
    mixture = torch.rand(2, 257) * 2  # >= 0, as relu/sigmoid give
    difference = torch.rand(2, 257) * 2 - 1
    post = PostConv()
    with torch.no_grad():
        post.net[-1].weight.zero_()
        post.net[-1].bias.zero_()
    once = SynthesisConfig(phase="source")  # the magnitudes with the source's phase, inverted once
    plain = binaural_waveform(spec, Masks(mixture, difference), 9000, synthesis=once)
    conv = binaural_waveform(spec, Masks(mixture, difference), 9000, post_conv=post, synthesis=once)
    assert torch.isfinite(conv).all() and torch.allclose(conv, plain, atol=1e-5)


def test_post_conv_model_trains_renders_any_length_and_refuses_block_streaming(tmp_path):
    from avgs.io.checkpoint import save_checkpoint, untrained_checkpoint
    from avgs.config import TrainConfig
    from avgs.render.renderer import SceneRenderer

    cfg = TrainConfig()
    cfg.acoustic.post_conv = True
    points = AudioPoints(torch.rand(200, 3) * 2 - 1, torch.randn(200, 52))
    model = AVGSModel(points, cfg.acoustic)
    mono_mag = dsp.stft(torch.randn(2, 22050)).abs()  # [2, F, N]
    (s_m, s_l, s_r), _ = model(torch.zeros(2, 3), torch.tensor([0.5, -0.5]), torch.ones(3) * 0.5, mono_mag)
    assert (s_l >= 0).all() and (s_r >= 0).all() and s_l.shape == mono_mag.shape
    s_l.sum().backward()
    assert model.binauralizer.post_conv.net[0].weight.grad.abs().sum() > 0

    rng = np.random.default_rng(0)
    ckpt = untrained_checkpoint(rng.uniform(0, 4, (300, 3)), [2.0, 2.0, 1.0], config=cfg)
    path = save_checkpoint(ckpt, tmp_path / "conv.ckpt")
    r = SceneRenderer.load(path)
    for n in (1, 100, 513, 30000):
        y = r.render((1.0, 1.0, 1.0), 30.0, rng.standard_normal(n)).binaural
        assert y.shape == (2, n) and np.all(np.isfinite(y))
    with pytest.raises(ValueError, match="conv head"):
        r.stream((1.0, 1.0, 1.0), 30.0)

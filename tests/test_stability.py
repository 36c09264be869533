"""Numerical stability on hard cases: each gives finite, bounded, sensible output with a
defined behaviour, and none warns or prints NaN.

Energy bound (checked on random poses and signals below): with per-ear gains
``g_c(f) = m_m(f) (1 +- m_d(f))`` and ``G_c = max_f |g_c(f)|``, the output energy of ear
c is at most ``ENERGY_FACTOR * G_c^2`` times the input's. The STFT-multiply-iSTFT is a
least-squares inverse of a modified STFT, whose norm is at most ``G_c`` in the interior;
the reflect padding at the two ends can add up to the energy of the padded edge
samples, hence a factor above 1 for short inputs (it tends to 1 for long ones). A
reverberant tail adds at most ``r^2 w / (1 - w)`` to a bin's power gain (the geometric sum
of its decay ``w`` per frame), and the bound includes it.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from avgs.acoustics.points import AudioPoints, alpha_from_features
from avgs.io.checkpoint import untrained_checkpoint
from avgs.config import STFT, AcousticConfig, SynthesisConfig, TrainConfig
from avgs.data.frame import SceneFrame
from avgs.render.renderer import HEADROOM_DB, HeadroomLimited, OneSourceModel, PositionClamped, SceneRenderer
from avgs.acoustics.synthesis import ear_gains
from avgs.acoustics.convolution import BlockConvolver, ConvolutionStream
from avgs.train.losses import volume_loss

pytestmark = pytest.mark.filterwarnings("error")  # any warning fails these tests

ROOM = np.array([[0.0, 0.0, 0.0], [6.0, 4.0, 3.0]])
SOURCE = np.array([4.5, 2.5, 1.2])
SR = 22050
ENERGY_FACTOR = 2.0
"Documented bound: ear energy <= ENERGY_FACTOR * (max gain of that ear)^2 * input energy."


def room_points(n=800, seed=0, scale=1.0):
    return np.random.default_rng(seed).uniform(ROOM[0], ROOM[1], size=(n, 3)) * scale


def room_checkpoint(**kwargs) -> dict:
    """An untrained scene of random points in ROOM, whose box is the room."""
    ckpt = untrained_checkpoint(room_points(), SOURCE, frame=SceneFrame(ROOM.mean(0), 1 / 3), seed=4, **kwargs)
    ckpt["scene"]["bounds"] = torch.tensor(ROOM, dtype=torch.float32)
    return ckpt


@pytest.fixture(scope="module")
def renderer():
    return SceneRenderer(room_checkpoint())


@pytest.fixture(scope="module")
def source_phase(renderer):
    """The same scene rendered from its spectrogram with the source's phase (the paper's synthesis)."""
    return SceneRenderer(room_checkpoint(), synthesis=SynthesisConfig(phase="source"))


def noise(n, seed=0):
    return np.random.default_rng(seed).standard_normal(n).astype(np.float32)


def check_output(out, length, capsys=None):
    y = out.binaural
    assert y.shape == (2, length) and y.dtype == np.float32
    assert np.all(np.isfinite(y)) and np.all(np.isfinite(out.mixture)) and np.all(np.isfinite(out.difference))
    assert np.all(out.mixture >= 0) and np.all(np.abs(out.difference) < 1)
    if capsys is not None:
        text = capsys.readouterr()
        assert "nan" not in (text.out + text.err).lower()


def energy_bound_holds(out, x, rt60=None) -> bool:
    """With a reverberant tail (gains r, RT60 per bin) a bin's power gain is at most
    ``g^2 + r^2 w / (1 - w)``, w the tail's power decay per frame (its geometric sum)."""
    gains = ear_gains(torch.from_numpy(out.mixture).double(), torch.from_numpy(out.difference).double()).numpy() ** 2  # [2, F]
    if out.reverb is not None:
        w = 10.0 ** (-6.0 * (STFT.hop_length / STFT.sample_rate) / rt60)  # [F]
        gains = gains + out.reverb.astype(np.float64) ** 2 * (w / (1.0 - w))
    e_in = float(np.sum(x.astype(np.float64) ** 2))
    e_out = np.sum(out.binaural.astype(np.float64) ** 2, axis=1)  # [2]
    bound = ENERGY_FACTOR * np.max(gains, axis=1) * e_in
    return bool(np.all(e_out <= bound + 1e-9))


# -- geometry -------------------------------------------------------------------------


def test_listener_exactly_on_an_audio_point(renderer, capsys):
    out = renderer.render(renderer.points[17].astype(np.float64), 30.0, noise(4000))
    check_output(out, 4000, capsys)
    assert 17 in out.listener_vicinity  # distance 0: the nearest point, direction guarded to zero


def test_listener_exactly_on_the_source(renderer, capsys):
    out = renderer.render(renderer.source, 45.0, noise(4000))
    check_output(out, 4000, capsys)
    assert out.theta == 0.0  # defined: a source at the listener counts as straight ahead
    assert set(out.listener_vicinity) == set(out.source_vicinity)


def test_two_points_at_the_same_position(capsys):
    pts = room_points(300)
    pts[1] = pts[0]
    pts[2] = pts[0]
    r = SceneRenderer(untrained_checkpoint(pts, SOURCE, seed=1))
    out = r.render(pts[0], 0.0, noise(3000))
    check_output(out, 3000, capsys)
    assert {0, 1, 2} <= set(out.listener_vicinity)


@pytest.mark.parametrize("n_points, percentile", [(1, 15.0), (2, 15.0), (5, 100.0), (40, 100.0)])
def test_vicinity_as_large_as_the_point_set(n_points, percentile, capsys):
    cfg = TrainConfig()
    cfg.acoustic = AcousticConfig(vicinity_percentile=percentile)
    pts = room_points(n_points, seed=2) if n_points > 1 else [[1.0, 1.0, 1.0]]
    ckpt = untrained_checkpoint(pts, SOURCE, config=cfg, frame=SceneFrame(ROOM.mean(0), 1 / 3))
    ckpt["scene"]["bounds"] = torch.tensor(ROOM, dtype=torch.float32)  # the room, not just its few points
    r = SceneRenderer(ckpt)
    out = r.render((2.0, 2.0, 1.6), 10.0, noise(2000))
    check_output(out, 2000, capsys)
    assert len(out.listener_vicinity) == r.vicinity_size <= n_points


def test_explicit_k_larger_than_the_points_is_capped(capsys):
    ckpt = untrained_checkpoint(room_points(30), SOURCE)
    ckpt["vicinity_k"] = 1000
    r = SceneRenderer(ckpt)
    assert r.vicinity_size == 30
    check_output(r.render((1.0, 1.0, 1.0), 0.0, noise(1000)), 1000, capsys)


@pytest.mark.parametrize("scale", [1e-6, 1e6])
def test_scene_coordinates_at_extreme_scales(scale, capsys):
    """The same scene in micrometres or in megametres renders the same (the frame normalises)."""
    unit = SceneRenderer(untrained_checkpoint(room_points(), SOURCE, seed=5))
    scaled = SceneRenderer(untrained_checkpoint(room_points(scale=scale), SOURCE * scale, seed=5))
    x = noise(3000)
    a = unit.render((2.0, 1.5, 1.6), 70.0, x)
    b = scaled.render((2.0 * scale, 1.5 * scale, 1.6 * scale), 70.0, x)
    check_output(b, 3000, capsys)
    assert np.allclose(a.binaural, b.binaural, rtol=1e-4, atol=1e-5)
    assert set(a.listener_vicinity) == set(b.listener_vicinity)


@pytest.mark.parametrize("far", [5.0, 100.0, 1e6, 1e300])
def test_positions_outside_the_scene_are_kept_inside_with_a_warning(renderer, far):
    """A listener or source outside the scene's box is moved onto its edge, with a warning that
    names both positions; the output is the edge's output, so its level stays bounded."""
    x = noise(3000)
    edge = renderer.render((6.0, 2.0, 1.6), 30.0, x)  # on the box's +x face (ROOM spans x 0..6)
    with pytest.warns(PositionClamped, match=r"listener \(.*\) is outside the scene.*using \(6, 2, 1.6\)"):
        out = renderer.render((6.0 + far, 2.0, 1.6), 30.0, x)
    assert np.array_equal(out.listener, [6.0, 2.0, 1.6]) and np.array_equal(out.binaural, edge.binaural)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OneSourceModel)  # said once per renderer: tests/test_rir_model.py
        with pytest.warns(PositionClamped, match="source"):
            moved = renderer.render((2.0, 2.0, 1.6), 30.0, x, source=(1.0, -far, 1.0))
    assert moved.source[1] == 0.0 and np.all(np.isfinite(moved.binaural))


def test_bad_positions_and_yaws_are_rejected(renderer):
    with pytest.raises(ValueError, match="finite"):
        renderer.render((math.inf, 0.0, 0.0), 0.0, noise(100))
    with pytest.raises(ValueError, match="yaw"):
        renderer.render((1.0, 1.0, 1.0), math.nan, noise(100))


# -- signals --------------------------------------------------------------------------


def test_silent_input_gives_exact_silence(renderer, capsys):
    out = renderer.render((2.0, 2.0, 1.6), 0.0, np.zeros(5000, dtype=np.float32))
    check_output(out, 5000, capsys)
    assert np.all(out.binaural == 0.0)


@pytest.mark.parametrize("kind", ["full-scale", "clipped"])
def test_full_scale_and_clipped_input(renderer, kind, capsys):
    t = np.arange(SR) / SR
    if kind == "full-scale":
        x = np.sign(np.sin(2 * np.pi * 220 * t)).astype(np.float32)  # +-1 square wave
        x[::97] = -x[::97]
    else:
        x = np.clip(3.0 * np.sin(2 * np.pi * 440 * t), -1, 1).astype(np.float32)  # hard-clipped sine
    out = renderer.render((1.5, 2.5, 1.6), -60.0, x)
    check_output(out, len(x), capsys)
    assert energy_bound_holds(out, x, renderer.rt60)


def test_dc_input_gives_constant_output_away_from_the_ends(renderer, capsys):
    x = np.full(3 * SR, 0.5, dtype=np.float32)
    out = renderer.render((3.0, 1.0, 1.6), 20.0, x)
    check_output(out, 3 * SR, capsys)
    # identical frames -> identical overlap-added output, once the tail has built up (2 s)
    inner = out.binaural[:, 2 * SR : -1024]
    assert np.allclose(inner, inner[:, :1], rtol=1e-4, atol=1e-6)


def test_pure_tone_keeps_its_frequency(renderer, capsys):
    f0 = 43 * SR / 512  # a bin centre, ~1851 Hz
    x = np.sin(2 * np.pi * f0 * np.arange(SR) / SR).astype(np.float32)
    out = renderer.render((2.0, 3.0, 1.6), 100.0, x)
    check_output(out, SR, capsys)
    for ch in out.binaural:
        spectrum = np.abs(np.fft.rfft(ch * np.hanning(SR)))
        if spectrum.max() > 1e-6:
            assert abs(np.argmax(spectrum) * SR / SR - f0) < 2.0  # peak at f0 (1 Hz bins)
    assert energy_bound_holds(out, x, renderer.rt60)


@pytest.mark.parametrize("length", [1, 2, 3, 100, 255, 256, 257, 511])
def test_input_shorter_than_one_stft_frame(renderer, source_phase, length, capsys):
    x = noise(length, seed=length)
    for r in (source_phase, renderer):
        out = r.render((2.0, 2.0, 1.6), 0.0, x)
        check_output(out, length, capsys)
        assert energy_bound_holds(out, x, r.rt60)
    stream = renderer.stream((2.0, 2.0, 1.6), 0.0)
    y = np.concatenate([stream.process(x[i : i + 50]) for i in range(0, length, 50)] + [stream.flush()], axis=1)
    assert np.allclose(y, out.binaural, atol=1e-5)  # the default render's


@pytest.mark.slow  # 27 s; block renders equal whole ones in the default suite: tests/test_bounded_memory.py
def test_ten_minutes_streamed_in_blocks_equal_one_shot(renderer):
    x = noise(10 * 60 * SR, seed=9) * 0.3  # 10 min, 13.2 M samples
    one_shot = renderer.render((2.5, 1.5, 1.6), 135.0, x).binaural
    stream = renderer.stream((2.5, 1.5, 1.6), 135.0)
    sizes = np.random.default_rng(0).integers(1, 20000, size=4000)
    bounds = np.minimum(np.concatenate([[0], np.cumsum(sizes)]), len(x))
    bounds = np.unique(np.append(bounds, len(x)))
    pieces, done = [], 0
    for a, b in zip(bounds[:-1], bounds[1:]):
        y = stream.process(x[a:b])
        assert y.shape[1] == 0 or (done + y.shape[1] <= b)  # output never runs ahead of input
        done += y.shape[1]
        pieces.append(y)
        assert b - done <= stream.latency  # and lags by at most the documented latency
    pieces.append(stream.flush())
    y = np.concatenate(pieces, axis=1)
    assert y.shape == one_shot.shape
    # float32 rounding, carried through the phase retrieval's 12 iterations (3.5e-5 measured)
    assert np.max(np.abs(y - one_shot)) <= 1e-4 * max(1.0, float(np.max(np.abs(one_shot))))
    with pytest.raises(ValueError, match="flushed"):
        stream.process(x[:10])


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nan_or_inf_input_is_rejected(renderer, bad):
    x = noise(1000)
    x[500] = bad
    with pytest.raises(ValueError, match="NaN or Inf"):
        renderer.render((2.0, 2.0, 1.6), 0.0, x)
    stream = renderer.stream((2.0, 2.0, 1.6), 0.0)
    with pytest.raises(ValueError, match="NaN or Inf"):
        stream.process(x)


# -- G and alpha ----------------------------------------------------------------------


def test_zero_and_unnormalised_quaternions_in_g():
    n = 6
    quats = torch.tensor([[0.0, 0, 0, 0], [2.0, 0, 0, 0], [1e-30, 0, 0, 1e-30], [3, 4, 0, 0], [1e20, 1e20, 0, 0], [0.5, 0.5, 0.5, 0.5]])
    sh = torch.randn(n, 48)
    alpha = alpha_from_features({"sh": sh, "r": quats}, "sh+r")
    assert torch.isfinite(alpha).all()
    q = alpha[:, 48:]
    assert torch.equal(q[0], torch.zeros(4))  # a zero quaternion stays zero: no direction to give
    assert torch.allclose(q[1:].norm(dim=-1), torch.ones(n - 1), atol=1e-5)
    with pytest.raises(ValueError, match="'s' parameters hold NaN or Inf"):
        alpha_from_features({"s": torch.tensor([[-math.inf, 0.0, 0.0]])}, "s")  # log of a zero scale
    # A checkpoint whose G holds such quaternions and zero scales still loads and renders.
    g = {"means": torch.zeros(n, 3), "quats": quats, "log_scales": torch.full((n, 3), -30.0), "sh": sh.reshape(n, 16, 3)}
    r = SceneRenderer(untrained_checkpoint(room_points(100), SOURCE, gaussians=g))
    assert np.all(np.isfinite(r.gaussians.rgb))
    check_output(r.render((1.0, 1.0, 1.0), 0.0, noise(500)), 500)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float16])
def test_volume_loss_over_52_dims_is_finite_and_non_negative(dtype):
    g = torch.Generator().manual_seed(0)
    rows = [
        torch.randn(64, 52, generator=g) * 0.1,  # tiny products (underflow directly)
        torch.randn(64, 52, generator=g) * 100.0,  # huge products (overflow directly)
        torch.zeros(4, 52),
        torch.full((4, 52), 65504.0 if dtype == torch.float16 else 3e38),  # the largest finite values
        -torch.ones(3, 52),
    ]
    for alpha in rows:
        a = alpha.to(dtype).requires_grad_(True)
        loss = volume_loss(a)
        loss.backward()
        assert torch.isfinite(loss) and loss >= 0
        assert torch.isfinite(a.grad).all()
    # Where the direct product is representable, it is sum log(1 + |prod|) of it (float64 reference).
    alpha = (torch.rand(32, 52, generator=g) * 1.5 + 0.3) * torch.sign(torch.randn(32, 52, generator=g))
    direct = torch.log1p(alpha.double().prod(-1).abs()).sum()
    assert torch.isfinite(alpha.prod(-1)).all()
    assert volume_loss(alpha.to(dtype)).double().item() == pytest.approx(direct.item(), rel=1e-3 if dtype == torch.float16 else 1e-5)


# -- randomised poses -----------------------------------------------------------------


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    x=st.floats(-1.0, 7.0),
    y=st.floats(-1.0, 5.0),
    z=st.floats(0.0, 3.0),
    yaw=st.floats(-720.0, 720.0),
    length=st.integers(1, 6000),
    seed=st.integers(0, 2**16),
    level=st.sampled_from([0.0, 1e-6, 1.0, 1e3]),
)
def test_random_poses_keep_energy_within_the_bound(renderer, x, y, z, yaw, length, seed, level):
    sig = noise(length, seed) * np.float32(level)
    with warnings.catch_warnings():  # poses outside the room are moved inside it: tested on their own
        warnings.simplefilter("ignore", PositionClamped)
        out = renderer.render((x, y, z), yaw, sig)
    check_output(out, length)
    assert energy_bound_holds(out, sig, renderer.rt60)
    assert -180.0 <= out.theta <= 180.0


def test_stream_rejects_bad_responses_and_blocks():
    with pytest.raises(ValueError, match=r"\[channels, length\]"):
        ConvolutionStream(np.ones(10))
    with pytest.raises(ValueError, match="finite"):
        ConvolutionStream(np.full((2, 10), np.nan))
    with pytest.raises(ValueError, match="power of two"):
        BlockConvolver(np.ones((2, 10)), 300)
    c = BlockConvolver(np.ones((2, 10)), 64)
    with pytest.raises(ValueError, match="blocks of 64"):
        c.process(np.zeros(63))
    with pytest.raises(ValueError, match="channels"):
        c.set_impulse(np.ones((1, 10)))


def test_audio_points_reject_non_finite_values():
    with pytest.raises(ValueError, match="NaN or Inf"):
        AudioPoints(torch.tensor([[0.0, math.nan, 0.0]]), torch.zeros(1, 4))


# -- bounded sound ---------------------------------------------------------------------


@pytest.mark.parametrize("level", [1e-30, 1e-6, 1e6, 1e30])
def test_any_finite_input_level_renders_the_same_sound_scaled(renderer, level):
    """Processing runs at unit peak: 1e30 does not overflow to silence, 1e-30 does not underflow."""
    x = noise(3000)
    ref = renderer.render((2.0, 2.0, 1.6), 15.0, x).binaural
    out = renderer.render((2.0, 2.0, 1.6), 15.0, x * np.float32(level)).binaural
    assert np.all(np.isfinite(out)) and np.max(np.abs(out)) > 0
    assert np.allclose(out / np.float32(level), ref, rtol=1e-4, atol=1e-6 * np.max(np.abs(ref)))


def _streamed(stream, x, size=700):
    return np.concatenate([stream.process(x[i : i + size]) for i in range(0, len(x), size)] + [stream.flush()], axis=1)


@pytest.mark.parametrize("synthesis", [None, SynthesisConfig(phase="filter", phase_iterations=0),
                                       SynthesisConfig(method="filter")], ids=["mid", "filter-phase", "filter"])
@pytest.mark.parametrize("level", [1e-25, 1e20, 1e30])
def test_any_finite_input_level_streams_the_same_sound_scaled(renderer, synthesis, level):
    """A stream takes its first sounding block's scale: 1e20 does not overflow the mid phase's float32
    powers to NaN (it did from 1e18), 1e-25 does not underflow."""
    r = renderer if synthesis is None else SceneRenderer(room_checkpoint(), synthesis=synthesis)
    x = noise(5000, seed=3)
    x[:1000] = 0.0  # silence first: the scale comes from the first block that sounds
    ref = _streamed(r.stream((2.0, 2.0, 1.6), 15.0), x)
    out = _streamed(r.stream((2.0, 2.0, 1.6), 15.0), x * np.float32(level))
    assert np.all(np.isfinite(out)) and np.max(np.abs(out)) > 0
    assert np.allclose(out / np.float32(level), ref, rtol=1e-4, atol=1e-6 * np.max(np.abs(ref)))
    whole = r.render((2.0, 2.0, 1.6), 15.0, x * np.float32(level)).binaural
    assert np.allclose(out, whole, rtol=1e-3, atol=1e-4 * np.max(np.abs(whole)))


def test_a_block_beyond_the_streams_range_is_refused_and_the_stream_goes_on(renderer):
    stream = renderer.stream((2.0, 2.0, 1.6), 15.0)
    x = noise(4000, seed=5)
    first = stream.process(x[:2000] * np.float32(1e-3))  # the scale: 2^-9
    with pytest.raises(ValueError, match=r"more than 2\^40 times the stream's scale"):
        stream.process(x[2000:3000] * np.float32(1e12))
    rest = [stream.process(x[2000:] * np.float32(1e-3)), stream.flush()]
    y = np.concatenate([first, *rest], axis=1)
    assert np.all(np.isfinite(y))
    ref = _streamed(renderer.stream((2.0, 2.0, 1.6), 15.0), x * np.float32(1e-3))
    assert np.allclose(y, ref, rtol=1e-4, atol=1e-6 * np.max(np.abs(ref)))


def loud_renderer(gain: float) -> SceneRenderer:
    """A scene whose mixture mask is ``gain`` in every bin (the head's bias), no tail."""
    cfg = TrainConfig()
    cfg.acoustic.reverb_tail = False
    ckpt = room_checkpoint(config=cfg)
    ckpt["binauralizer"]["mix_head.weight"].zero_()
    ckpt["binauralizer"]["mix_head.bias"].fill_(gain)
    return SceneRenderer(ckpt)


def test_a_filter_over_the_headroom_is_scaled_down_with_a_warning():
    x = noise(SR)
    quiet = loud_renderer(2.0).render((2.0, 2.0, 1.6), 0.0, x)  # +6 dB at most (+12 with m_d): inside
    with pytest.warns(HeadroomLimited, match="scaled to the 24 dB headroom"):
        loud = loud_renderer(1e4).render((2.0, 2.0, 1.6), 0.0, x)  # +80 dB
    limit = 10 ** (HEADROOM_DB / 20)
    gains = ear_gains(torch.from_numpy(loud.mixture).double(), torch.from_numpy(loud.difference).double())
    assert float(gains.max()) == pytest.approx(limit, rel=1e-4)  # the loudest bin sits at the headroom
    assert np.max(np.abs(loud.binaural)) <= limit * np.max(np.abs(x)) * (1 + 1e-6)
    assert np.all(quiet.mixture == pytest.approx(2.0))  # a filter inside the headroom is left alone
    with pytest.warns(HeadroomLimited):
        loud_filter = loud_renderer(1e4).binaural_filter((2.0, 2.0, 1.6), 0.0)  # streams get the same bounded filter
    response = np.abs(np.fft.rfft(loud_filter.impulse, 8192))  # the minimum-phase filter's magnitude, finely sampled
    assert float(response.max()) == pytest.approx(limit, rel=0.02)


def test_non_finite_weights_are_an_error_not_silence():
    ckpt = untrained_checkpoint(room_points(), SOURCE, seed=4)
    ckpt["binauralizer"]["diff_head.bias"].fill_(math.inf)
    ckpt["binauralizer"]["mix_head.bias"].fill_(math.nan)
    r = SceneRenderer(ckpt)
    with pytest.raises(ValueError, match="NaN or Inf masks"):
        r.render((2.0, 2.0, 1.6), 0.0, noise(1000))


@pytest.mark.parametrize("iterations", [0, 8])
def test_a_long_input_rendered_in_blocks_equals_one_pass(renderer, iterations, monkeypatch):
    """Long inputs are rendered block by block with a margin that covers the tail and the
    phase iterations (bounded memory); the result is the one-pass render."""
    import avgs.render.renderer

    r = SceneRenderer(room_checkpoint(), synthesis=SynthesisConfig(method="spectrogram", phase_iterations=iterations))
    x = noise(12 * SR, seed=3)
    x[5 * SR : 6 * SR] = 0.0  # exact silence: the tail's fill phase must follow the absolute frame
    one_pass = r.render((2.0, 2.0, 1.6), 40.0, x).binaural
    monkeypatch.setattr(avgs.render.binaural, "RENDER_BLOCK_FRAMES", 300)  # ~1.7 s blocks: several of them
    blocked = r.render((2.0, 2.0, 1.6), 40.0, x).binaural
    # Float rounding, amplified: the tail's power is an FFT convolution whose rounding is
    # relative to the loudest frame, and its square root turns a 1e-9 power error in the
    # decaying silence into 3e-5 of amplitude; fast Griffin-Lim's momentum amplifies it
    # further there (measured 1.8e-4 of the peak with 8 iterations: -75 dB).
    peak = np.max(np.abs(one_pass))
    assert np.max(np.abs(blocked - one_pass)) <= (1e-4 if iterations == 0 else 1e-3) * peak
    loud = np.abs(x) > 0  # where the source plays, the two agree to single-precision rounding
    tol = 1e-6 if iterations == 0 else 1e-4
    assert np.max(np.abs(blocked - one_pass)[:, loud]) <= tol * peak


def test_audio_files_with_absurd_headers_are_refused(tmp_path):
    import soundfile as sf

    from avgs.io.audio_input import read_mono

    for rate in (1, 2000, 1_000_000):
        path = tmp_path / f"r{rate}.wav"
        sf.write(path, np.zeros(64, dtype=np.float32), rate)
        with pytest.raises(ValueError, match=f"{path.name}: sample rate {rate} Hz"):
            read_mono(path, SR)
    ok = tmp_path / "ok.wav"
    sf.write(ok, noise(4410), 44100)
    assert read_mono(ok, SR).shape == (2205,)


def test_all_finite_is_isfinite_all_whatever_the_sum_does():
    """The renderer's finiteness check by the sum agrees with ``isfinite(t).all()``: a NaN or an Inf anywhere
    is caught (Infs of both signs too, whose sum is NaN), and finite values whose sum overflows are not
    taken for an Inf."""
    import torch

    from avgs.render.tasks import all_finite

    rng = torch.Generator().manual_seed(0)
    x = torch.randn(2, 20096, generator=rng)
    cases = [x, torch.zeros(0), torch.full((10,), 3e38), torch.randn(4, dtype=torch.complex64), x.double()]
    for value in (float("nan"), float("inf"), -float("inf")):
        y = x.clone()
        y[1, 12345] = value
        cases.append(y)
    cases.append(torch.tensor([float("inf"), -float("inf")]))
    for t in cases:
        assert all_finite(t) == bool(torch.isfinite(t).all())
    assert all_finite(torch.full((10,), 3e38)) and not all_finite(cases[-1])

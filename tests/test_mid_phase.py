"""The default synthesis: one phase retrieved for the mid magnitudes, shared by both ears
(avgs.acoustics.synthesis.mid_phase_waveform), and its block stream (avgs.render.mid_phase_stream)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from avgs.config import STFT
from avgs import dsp
from avgs.acoustics.synthesis import Masks, ear_magnitudes, mid_phase_waveform, pose_parts, source_parts
from avgs.config import MID_PHASE_ITERATIONS, SynthesisConfig
from avgs.render.mid_phase_stream import MidPhaseStream

F = STFT.n_freq


def _noise(n, seed=0):
    return np.random.default_rng(seed).standard_normal(n).astype(np.float32)


def test_a_gain_only_pose_gives_the_gained_input_back():
    """Ear gains flat in frequency and no tail: the target magnitudes are those of g x, a
    consistent spectrogram, so the retrieved phase keeps the source's and each ear is its
    gain times the input."""
    x = torch.from_numpy(_noise(22050, 1))
    masks = Masks(torch.full((1, F), 0.8), torch.full((1, F), 0.25))  # left 0.8 * 1.25 = 1.0, right 0.8 * 0.75 = 0.6
    y, ears = mid_phase_waveform(dsp.stft(x[None]), masks, 22050)
    assert y.shape == (1, 2, 22050) and ears.shape == (1, 2, F, 173)
    assert torch.allclose(y[0, 0], x, atol=2e-3 * float(x.abs().max()))
    assert torch.allclose(y[0, 1], 0.6 * x, atol=2e-3 * float(x.abs().max()))


@pytest.mark.parametrize("tail", [False, True])
def test_pose_parts_are_the_ear_magnitudes(tail):
    """The per-clip and per-pose halves of the default synthesis give ear_magnitudes' s_m, s_l,
    s_r (frame-major), and a first guess with the mid magnitudes."""
    g = torch.Generator().manual_seed(3)
    spec = dsp.stft(torch.from_numpy(_noise(5000, 2))[None])  # [1, F, 40]
    masks = Masks(torch.rand(1, F, generator=g), 2 * torch.rand(1, F, generator=g) - 1,
                  torch.rand(1, 2, F, generator=g) if tail else None, torch.full((F,), 0.7) if tail else None)
    start, mid, ears = pose_parts(source_parts(spec, masks.decay), masks)
    s_m, s_l, s_r = ear_magnitudes(spec.abs(), masks)
    # Compared in power: the tail's FFT convolution leaves rounding of its largest value
    # (~1e-7 of it) where it is 0 (the first frame), which a square root magnifies.
    atol = 1e-6 * float(s_m.square().max())
    torch.testing.assert_close(mid.square(), s_m.transpose(-1, -2).square(), rtol=1e-4, atol=atol)
    torch.testing.assert_close(ears.square(), torch.stack([s_l, s_r], dim=1).transpose(-1, -2).square(),
                               rtol=1e-4, atol=atol)
    torch.testing.assert_close(start.abs(), mid, rtol=1e-5, atol=1e-6)
    if tail:
        with pytest.raises(ValueError, match="tail"):
            pose_parts(source_parts(spec), masks)  # parts made without the scene's decay


def test_a_clip_heard_from_many_poses_is_analysed_once(tail_checkpoint, monkeypatch):
    """The renderer keeps the last clip's source analysis: the next pose of the same clip
    only does its own part, with the same output as a renderer that did not keep it; a
    changed clip (even changed in place by the caller) is analysed anew."""
    import avgs.acoustics.synthesis
    import avgs.render.binaural
    from avgs.render.renderer import SceneRenderer

    calls = []
    analyse = avgs.acoustics.synthesis.source_parts
    for module in (avgs.render.binaural, avgs.acoustics.synthesis):
        monkeypatch.setattr(module, "source_parts", lambda *a, **k: calls.append(1) or analyse(*a, **k))
    r, other = SceneRenderer(tail_checkpoint()), SceneRenderer(tail_checkpoint())
    x = _speech_like(22050, seed=4)
    poses = [((2.0, 1.0, 1.6), 45.0), ((4.0, 3.0, 1.6), -120.0), ((1.0, 2.5, 1.6), 10.0)]
    first = [r.render(*pose, x).binaural for pose in poses]
    assert len(calls) == 1
    for pose, y in zip(poses, first):
        other.render(*pose, x[:3000])  # another clip in between: x is analysed anew
        assert np.array_equal(other.render(*pose, x).binaural, y)
    calls.clear()
    x[1000:1100] *= -1.0  # the caller changes the clip in place (where it is not silent)
    y = r.render(*poses[0], x).binaural
    assert len(calls) == 1 and not np.array_equal(y, first[0])
    other.render(*poses[0], x[:3000])
    assert np.array_equal(other.render(*poses[0], x).binaural, y)
    calls.clear()
    long = _speech_like(13 * 22050, seed=5)  # a file rather than a clip: not kept
    r.render(*poses[0], long), r.render(*poses[1], long)
    assert len(calls) == 2


def _speech_like(n, seed=0):
    """Noise bursts with gaps: a tail rings on in the gaps, where the source's phase is no guide."""
    x = _noise(n, seed)
    envelope = (np.sin(np.arange(n) * 2 * np.pi * 3.0 / 22050) > 0.2).astype(np.float32)
    return x * envelope


def _off_target(renderer, synthesis, x, pose=((2.0, 1.0, 1.6), 45.0)):
    """Relative distance of the waveform's own STFT magnitudes from the predicted ones (what MAG rewards)."""
    out = renderer.render(*pose, x, magnitudes=True, synthesis=synthesis)
    got = dsp.magnitude(torch.from_numpy(out.binaural).double()).numpy()
    return float(np.linalg.norm(got - out.magnitudes) / np.linalg.norm(out.magnitudes))


def test_the_retrieved_phase_lands_nearer_the_predicted_magnitudes(tail_renderer):
    """The retrieval brings the waveform's own magnitudes towards B's, more with more
    iterations, and nearer than the filter's or the source's phase. (Against eight
    iterations per ear, on trained scenes and their ground truth: docs/results.md#synthesis;
    this scene's two ears have unrelated tails, the least favourable case for one phase.)"""
    x = _speech_like(22050)
    errors = {name: _off_target(tail_renderer, s, x) for name, s in {
        "filter": SynthesisConfig(phase="filter"),
        "source": SynthesisConfig(phase="source"),
        "mid 0": SynthesisConfig(phase_iterations=0),  # the start: the source's phase (the fill phase where silent)
        "mid 4": SynthesisConfig(phase_iterations=4),
        "mid": SynthesisConfig(),
    }.items()}
    assert errors["mid"] < errors["mid 4"] < errors["filter"] < min(errors["mid 0"], errors["source"])


def test_synthesis_iterations_default_by_phase():
    assert SynthesisConfig().iterations == MID_PHASE_ITERATIONS
    assert SynthesisConfig(phase="filter").iterations == 0 and SynthesisConfig(phase="source").iterations == 0
    assert SynthesisConfig(phase="source", phase_iterations=3).iterations == 3
    assert SynthesisConfig(method="filter", phase_iterations=3).iterations == 0  # a convolution retrieves nothing
    for bad in (dict(phase="noise"), dict(phase_iterations=-1), dict(phase_momentum=1.0)):
        with pytest.raises(ValueError):
            SynthesisConfig(**bad)


def _streamed(stream, x, sizes_seed=1, top=3000):
    sizes = np.random.default_rng(sizes_seed).integers(1, top, size=4 * len(x) // top + 8)
    bounds = np.unique(np.minimum(np.concatenate([[0], np.cumsum(sizes), [len(x)]]), len(x)))
    pieces, done = [], 0
    for a, b in zip(bounds[:-1], bounds[1:]):
        y = stream.process(x[a:b])
        done += y.shape[1]
        assert done <= b and b - done <= stream.latency  # never ahead of the input, never later than documented
        pieces.append(y)
    return np.concatenate(pieces + [stream.flush()], axis=1)


@pytest.mark.parametrize("length", [1, 200, 300, 22050, 3 * 22050 + 17])
def test_blocks_of_any_size_give_the_render(tail_renderer, length):
    """Each block's phase is retrieved with the iterations' reach on both sides: in exact
    arithmetic the same waveform as one pass over the whole input. In float32 the
    iterations carry rounding along, so the bound is the render's own distance from the
    same synthesis in float64."""
    x = _speech_like(length, seed=length)
    pose = ((2.0, 1.0, 1.6), 45.0)
    one_shot = tail_renderer.render(*pose, x).binaural
    m = tail_renderer.response(*pose).masks
    with torch.inference_mode():
        exact, _ = mid_phase_waveform(dsp.stft(torch.from_numpy(x.astype(np.float64))[None]), m.to(torch.float64), length)
    peak = max(1e-6, float(np.max(np.abs(one_shot))))
    rounding = float(np.max(np.abs(one_shot - exact[0].numpy()))) + 1e-6 * peak
    assert rounding < 1e-3 * peak
    y = _streamed(tail_renderer.stream(*pose), x)
    assert y.shape == one_shot.shape
    assert np.max(np.abs(y - one_shot)) <= 3 * rounding
    for block_frames in (1, 5, 40):  # the cut between blocks leaves no trace
        other = _streamed(MidPhaseStream(m, synthesis=SynthesisConfig(), block_frames=block_frames), x, sizes_seed=2)
        assert np.max(np.abs(other - y)) <= 3 * rounding


def test_stream_latency_is_the_reach_and_one_block():
    m = Masks(torch.ones(1, F), torch.zeros(1, F))
    s = MidPhaseStream(m)
    assert s.latency == (16 + 4 * (MID_PHASE_ITERATIONS + 2) + 2) * 128 + 256  # 8704 samples, 0.39 s
    assert MidPhaseStream(m, synthesis=SynthesisConfig(phase_iterations=0)).latency < s.latency


def test_stream_refuses_what_it_cannot_stream():
    m = Masks(torch.ones(1, F), torch.zeros(1, F))
    with pytest.raises(ValueError, match="mid phase"):
        MidPhaseStream(m, synthesis=SynthesisConfig(phase="filter"))
    with pytest.raises(ValueError, match="one pose"):
        MidPhaseStream(Masks(torch.ones(2, F), torch.zeros(2, F)))
    s = MidPhaseStream(m)
    with pytest.raises(ValueError, match="NaN or Inf"):
        s.process(np.array([0.0, np.nan], dtype=np.float32))
    s.flush()
    with pytest.raises(ValueError, match="flushed"):
        s.process(np.zeros(10, dtype=np.float32))

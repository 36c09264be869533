"""Inference caches only: the model with :meth:`AVGSModel.precompute` and a cached C_S
computes what the model computes without them, for every variant of F and B."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from avgs.data.frame import signed_direction
from avgs.acoustics.model import AVGSModel
from avgs.acoustics.points import AudioPoints
from avgs.config import AcousticConfig


def make_model(n=700, seed=0, **cfg) -> AVGSModel:
    """A model whose every output depends on its input: the heads that start at zero
    (mixture, reverberant gains) get random weights, as a trained model has."""
    g = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    pts = AudioPoints(torch.rand(n, 3, generator=g) * 2 - 1, torch.randn(n, 52, generator=g))
    model = AVGSModel(pts, AcousticConfig(**cfg)).eval()
    b = model.binauralizer
    with torch.no_grad():
        heads = [b.mix_head] + ([b.reverb.head] if b.reverb is not None else [])
        for head in heads:
            head.weight.normal_(0.0, 0.3, generator=g)
        if b.reverb is not None:
            b.reverb.log_rt60.uniform_(-3.0, 0.5, generator=g)
    return model


@pytest.mark.parametrize(
    "cfg",
    [
        {},
        {"direction_harmonics": 3, "position_frequencies": 10},
        {"direction_every_layer": False},
        {"direction_encoding": "fourier"},
        {"mixture_activation": "sigmoid"},
        {"use_context": False},
        {"field_layers": 1},
        {"field_layers": 4, "vicinity_percentile": 100.0},
        {"reverb_tail": False},
    ],
    ids=["default", "harmonic-3-pe-10", "direction-first-layer", "fourier", "sigmoid", "no-context", "one-layer-F",
         "deep-F-all-points", "no-reverb-tail"],
)
def test_cached_masks_equal_uncached(cfg):
    model = make_model(**cfg)
    cache = model.precompute()
    rng = np.random.default_rng(1)
    source = torch.tensor([0.4, -0.3, 0.1])
    with torch.no_grad():
        cached_source = model.source_context(source, cache)
        for _ in range(5):
            lis = torch.tensor(rng.uniform(-1, 1, (1, 3)), dtype=torch.float32)
            theta = signed_direction(lis, torch.tensor([float(rng.uniform(-math.pi, math.pi))]), source)
            ref = model.masks(lis, theta, source)  # no cache at all, as in training
            out = model.masks(lis, theta, source, cached_source, cache)
            assert set(out.listener_vicinity[0].tolist()) == set(ref.listener_vicinity[0].tolist())
            assert set(out.source_vicinity.tolist()) == set(ref.source_vicinity.tolist())
            assert torch.allclose(out.mixture, ref.mixture, rtol=1e-4, atol=1e-5)
            assert torch.allclose(out.difference, ref.difference, rtol=1e-4, atol=1e-5)
            assert out.difference.std() > 1e-3  # the comparison is not between constants
            if model.binauralizer.reverb is None:
                assert out.reverb is None and ref.reverb is None
            else:
                assert out.reverb.shape == (1, 2, 257) and out.reverb.std() > 0.01  # pose- and frequency-dependent
                assert torch.allclose(out.reverb, ref.reverb, rtol=1e-4, atol=1e-5)
                assert torch.equal(out.decay, ref.decay)


def test_cache_is_only_a_cache():
    """The model keeps no state between poses: a second pose does not change the first's result."""
    model = make_model()
    cache = model.precompute()
    src = torch.zeros(3)
    with torch.no_grad():
        cs = model.source_context(src, cache)
        a = model.masks(torch.tensor([[0.5, 0.5, 0.0]]), torch.tensor([0.3]), src, cs, cache)
        model.masks(torch.tensor([[-0.5, 0.2, 0.1]]), torch.tensor([-1.0]), src, cs, cache)
        b = model.masks(torch.tensor([[0.5, 0.5, 0.0]]), torch.tensor([0.3]), src, cs, cache)
    assert torch.equal(a.mixture, b.mixture) and torch.equal(a.difference, b.difference)


def test_the_renderer_runs_the_model_with_its_caches(tmp_path):
    """SceneRenderer's masks are the uncached model's masks for the same pose."""
    from avgs.io.checkpoint import save_checkpoint, untrained_checkpoint
    from avgs.render.renderer import SceneRenderer

    rng = np.random.default_rng(0)
    path = save_checkpoint(untrained_checkpoint(rng.uniform(0, 4, (400, 3)), [2.0, 1.0, 1.0]), tmp_path / "s.ckpt")
    r = SceneRenderer.load(path)
    for listener, yaw in (((1.0, 3.0, 1.2), 30.0), ((3.5, 0.5, 0.4), -120.0)):
        out = r.masks(listener, yaw)
        lis, theta, src = r.pose(listener, yaw)
        with torch.no_grad():
            ref = r.model.masks(lis, theta, src)
        assert np.allclose(out.mixture, ref.mixture[0].numpy(), rtol=1e-4, atol=1e-5)
        assert np.allclose(out.difference, ref.difference[0].numpy(), rtol=1e-4, atol=1e-5)
        assert out.theta == pytest.approx(math.degrees(float(theta[0])))

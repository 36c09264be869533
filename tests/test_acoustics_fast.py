"""The fast inference path (:mod:`avgs.acoustics.fast`) computes what the model computes."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from avgs.acoustics.fast import FastMasks, signed_direction
from avgs.acoustics.model import AVGSModel
from avgs.acoustics.model import signed_direction as model_signed_direction
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
        {"direction_encoding": "embedding"},
        {"direction_encoding": "harmonic", "direction_harmonics": 3, "position_frequencies": 4},
        {"direction_every_layer": False},
        {"direction_encoding": "fourier"},
        {"mixture_activation": "sigmoid"},
        {"use_context": False},
        {"field_layers": 1},
        {"field_layers": 4, "vicinity_percentile": 100.0},
        {"reverb_tail": False},
    ],
    ids=["default", "embedding", "harmonic-low-pe", "direction-first-layer", "fourier", "sigmoid", "no-context", "one-layer-F", "deep-F-all-points", "no-reverb-tail"],
)
def test_fast_masks_equal_the_model(cfg):
    model = make_model(**cfg)
    fast = FastMasks(model)
    rng = np.random.default_rng(1)
    source = torch.tensor([0.4, -0.3, 0.1])
    cached = fast.source_context(tuple(source.tolist()))
    with torch.no_grad():
        ref_cached = model.source_context(source)
        for _ in range(5):
            lis = torch.tensor(rng.uniform(-1, 1, 3), dtype=torch.float32)
            yaw = float(rng.uniform(-math.pi, math.pi))
            theta = signed_direction(lis.tolist(), yaw, source.tolist())
            assert theta == pytest.approx(float(model_signed_direction(lis[None], torch.tensor([yaw]), source)[0]), abs=1e-6)
            ref = model.masks(lis[None], torch.tensor([theta]), source, ref_cached)
            mix, diff, idx, reverb = fast.masks(tuple(lis.tolist()), theta, cached)
            assert set(idx.tolist()) == set(ref.listener_vicinity[0].tolist())
            assert set(cached[1].tolist()) == set(ref_cached[1].tolist())
            assert torch.allclose(mix, ref.mixture[0], rtol=1e-4, atol=1e-5)
            assert torch.allclose(diff, ref.difference[0], rtol=1e-4, atol=1e-5)
            if model.binauralizer.reverb is None:
                assert reverb is None and ref.reverb is None
            else:
                assert reverb.shape == (2, 257) and reverb.std() > 0.01  # pose- and frequency-dependent
                assert torch.allclose(reverb, ref.reverb[0], rtol=1e-4, atol=1e-5)


def test_fast_masks_repeat_calls_are_independent():
    """Work buffers are reused: a second pose must not disturb a result already returned."""
    fast = FastMasks(make_model())
    cached = fast.source_context((0.0, 0.0, 0.0))
    a = fast.masks((0.5, 0.5, 0.0), 0.3, cached)
    a_copy = [t.clone() for t in a]
    fast.masks((-0.5, 0.2, 0.1), -1.0, cached)
    for x, y in zip(a, a_copy):
        assert torch.equal(x, y)

"""The interaural time difference (avgs.acoustics.interaural): Woodworth's head, the ears' delays,
the scale fitted to recordings, and every synthesis of the binaural task carrying it, measured by
the GCC-PHAT metric of avgs.evaluation.spatial on white noise."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from avgs.acoustics.interaural import DEFAULT_SCALE, ear_delays, fit_scale, interaural_delay, woodworth_shape
from avgs.config import SynthesisConfig, TrainConfig
from avgs.evaluation import spatial
from avgs.io.checkpoint import untrained_checkpoint
from avgs.render.renderer import SceneRenderer

ROOM = np.array([[0.0, 0.0, 0.0], [6.0, 4.0, 3.0]])
LISTENER = (3.0, 2.0, 1.5)
SOURCE = (3.0, 3.5, 1.5)  # +y of the listener


def test_woodworths_head():
    theta = torch.tensor([0.0, math.pi / 2, -math.pi / 2, math.pi / 6, math.pi - math.pi / 6, math.pi])
    shape = woodworth_shape(theta)
    assert shape[0] == 0 and abs(float(shape[-1])) < 1e-6  # in front and behind: no difference
    assert float(shape[1]) == pytest.approx(math.pi / 2 + 1) and float(shape[2]) == pytest.approx(-(math.pi / 2 + 1))
    assert float(shape[3]) == pytest.approx(math.pi / 6 + 0.5) and float(shape[4]) == pytest.approx(float(shape[3]))
    tau = interaural_delay(theta, DEFAULT_SCALE)
    assert float(tau[1]) * 1e6 == pytest.approx(0.0875 / 343.0 * (math.pi / 2 + 1) * 1e6)  # 656 us at 90 degrees
    d = ear_delays(theta, DEFAULT_SCALE)  # [6, 2]: only the lagging ear is delayed
    assert float(d[1, 0]) == 0 and float(d[1, 1]) == pytest.approx(float(tau[1]))  # source left: the right ear lags
    assert float(d[2, 1]) == 0 and float(d[2, 0]) == pytest.approx(-float(tau[2]))
    assert torch.all(d >= 0)


def test_fit_scale_recovers_a_head_from_noisy_itds():
    rng = np.random.default_rng(0)
    theta = rng.uniform(-math.pi, math.pi, 200)
    true = 3.1e-4
    itd = -true * woodworth_shape(torch.from_numpy(theta)).numpy() + rng.normal(0, 2e-5, 200)  # metric sign: left leads < 0
    itd[:10] = -itd[:10]  # a few lags that reverberation won: left out by their sign
    assert fit_scale(theta, itd) == pytest.approx(true, rel=0.03)
    assert fit_scale(theta[:2], itd[:2]) == DEFAULT_SCALE  # too few to say
    assert fit_scale(np.zeros(50), np.zeros(50)) == DEFAULT_SCALE  # all in front: nothing to fit


def _renderer(interaural: bool = True, scale: float = DEFAULT_SCALE) -> SceneRenderer:
    cfg = TrainConfig()
    cfg.acoustic.interaural_delay = interaural
    pts = np.random.default_rng(1).uniform(ROOM[0], ROOM[1], size=(400, 3))
    ckpt = untrained_checkpoint(pts, np.array(SOURCE), config=cfg, seed=2)
    if interaural:
        ckpt["binauralizer"]["itd_scale"] = torch.tensor(scale)
    return SceneRenderer(ckpt)


SYNTHESES = {
    "mid (default)": SynthesisConfig(),
    "filter": SynthesisConfig(method="filter"),
    "filter's phase": SynthesisConfig(phase="filter"),
    "source's phase": SynthesisConfig(phase="source"),
    "source's phase + 8": SynthesisConfig(phase="source", phase_iterations=8),
}


@pytest.mark.parametrize("name", list(SYNTHESES))
def test_every_synthesis_carries_the_itd_of_the_sources_side(name):
    r = _renderer(scale=3.0e-4)
    noise = np.random.default_rng(3).standard_normal(22050).astype(np.float32)
    want = 3.0e-4 * (math.pi / 2 + 1)  # 771 us: the source straight to one side
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        left = r.render(LISTENER, 0.0, noise, synthesis=SYNTHESES[name]).binaural  # facing +x: the source on the left
        right = r.render(LISTENER, 180.0, noise, synthesis=SYNTHESES[name]).binaural
        ahead = r.render(LISTENER, 90.0, noise, synthesis=SYNTHESES[name]).binaural
    assert spatial.itd(left) * 1e6 == pytest.approx(-want * 1e6, abs=20)  # the left ear leads: negative
    assert spatial.itd(right) * 1e6 == pytest.approx(want * 1e6, abs=20)
    assert abs(spatial.itd(ahead)) * 1e6 < 20


def test_the_filter_carries_the_itd_and_the_stream_equals_the_render():
    r = _renderer(scale=2.5e-4)
    h = r.binaural_filter(LISTENER, 0.0).impulse  # [2, L]
    assert spatial.response_itd(h) * 1e6 == pytest.approx(-2.5e-4 * (math.pi / 2 + 1) * 1e6, abs=25)
    x = np.random.default_rng(4).standard_normal(9000).astype(np.float32)
    s = r.stream(LISTENER, 30.0)
    y = np.concatenate([s.process(x[:3001]), s.process(x[3001:]), s.flush()], axis=1)
    one = r.render(LISTENER, 30.0, x).binaural
    assert np.max(np.abs(y - one)) < 1e-4 * np.max(np.abs(one))


def test_a_model_without_ear_delays_is_unchanged():
    """Checkpoints from before the ITD (interaural_delay off) render both ears at once, as they did."""
    r = _renderer(interaural=False)
    assert r.model.binauralizer.itd_scale is None and r.response(LISTENER, 0.0).masks.delay is None
    noise = np.random.default_rng(5).standard_normal(22050).astype(np.float32)
    assert abs(spatial.itd(r.render(LISTENER, 0.0, noise).binaural)) < 1e-6

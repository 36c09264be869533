"""Checkpoint round trip and validation, and the inference object on an untrained checkpoint."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import torch

from avgs.io.checkpoint import (
    FORMAT_VERSION,
    load_checkpoint,
    save_checkpoint,
    untrained_checkpoint,
)
from avgs.data.frame import SceneFrame
from avgs.data.scene_geometry import outline_from_metadata
from avgs.render.renderer import SceneRenderer

ROOM = np.array([[0.0, 0.0, 0.0], [6.0, 4.0, 3.0]])
SOURCE = np.array([4.5, 2.5, 1.2])


@pytest.fixture(scope="module")
def ckpt_path(tmp_path_factory):
    rng = np.random.default_rng(0)
    pts = rng.uniform(ROOM[0], ROOM[1], size=(400, 3))
    frame = SceneFrame(ROOM.mean(0), 1.0 / 3.0)
    quad = [[0, 0, 0], [6, 0, 0], [6, 0, 3], [0, 0, 3]]
    outline = outline_from_metadata({"surfaces": [{"name": "wall", "corners": quad}]})
    ckpt = untrained_checkpoint(pts, SOURCE, frame=frame, outline_world=outline, seed=3)
    return save_checkpoint(ckpt, tmp_path_factory.mktemp("ckpt") / "scene.ckpt")


def test_round_trip_with_weights_only(ckpt_path):
    raw = torch.load(ckpt_path, weights_only=True)  # plain tensors and values only
    assert raw["format_version"] == FORMAT_VERSION
    ckpt = load_checkpoint(ckpt_path)
    r = SceneRenderer.load(ckpt_path)
    frame = SceneFrame.from_dict(ckpt["frame"])
    assert np.allclose(r.points, frame.to_world(ckpt["audio_points"]["X"].numpy()), atol=1e-5)
    assert r.points.shape == (400, 3) and r.alpha.shape == (400, 52)
    assert np.allclose(r.source, SOURCE, atol=1e-5)
    assert r.sample_rate == 22050 and r.gaussians is None
    assert r.outline.shape == (4, 2, 3)
    assert np.all(r.bounds[0] <= r.points.min(0) + 1e-5) and np.all(r.bounds[1] >= r.points.max(0) - 1e-5)
    with pytest.raises(ValueError):
        r.points[0, 0] = 1.0  # read-only for the GUI thread


def test_outline_edges_are_shared_once():
    a, b, c, d, e, f = [0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [1, 0, 1], [0, 0, 1]
    seg = outline_from_metadata({"surfaces": [[a, b, c, d], {"vertices": [a, b, e, f]}]})
    assert seg.shape == (7, 2, 3)  # 4 + 4 edges, the edge a-b counted once
    assert outline_from_metadata(None) is None and outline_from_metadata({"surfaces": "x"}) is None


def test_bad_files_give_clear_errors(tmp_path, ckpt_path):
    with pytest.raises(FileNotFoundError, match="missing.ckpt"):
        load_checkpoint(tmp_path / "missing.ckpt")
    junk = tmp_path / "junk.ckpt"
    junk.write_bytes(b"definitely not a checkpoint")
    with pytest.raises(ValueError, match="junk.ckpt.*not an AV-GS checkpoint"):
        load_checkpoint(junk)
    ckpt = load_checkpoint(ckpt_path)
    for name, edit, message in (
        ("old.ckpt", lambda c: c.update(format_version=99), "version 99"),
        ("nokeys.ckpt", lambda c: c.pop("binauralizer"), "missing binauralizer"),
        ("dict.ckpt", lambda c: c.clear(), "format_version"),
    ):
        bad = dict(ckpt)
        edit(bad)
        save_checkpoint(bad, tmp_path / name)
        with pytest.raises(ValueError, match=message):
            load_checkpoint(tmp_path / name)


def test_save_is_atomic_and_leaves_no_temp_files(tmp_path, ckpt_path):
    ckpt = load_checkpoint(ckpt_path)
    out = save_checkpoint(ckpt, tmp_path / "a.ckpt")
    save_checkpoint(ckpt, out)  # overwrite in place
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.ckpt"]


@pytest.mark.parametrize("length", [1, 100, 511, 4000])
def test_render_any_length(ckpt_path, length):
    r = SceneRenderer.load(ckpt_path)
    mono = np.random.default_rng(length).standard_normal(length).astype(np.float32)
    out = r.render((1.0, 1.0, 1.6), 30.0, mono)
    assert out.binaural.shape == (2, length) and out.binaural.dtype == np.float32
    assert np.all(np.isfinite(out.binaural))
    assert out.mixture.shape == out.difference.shape == (257,)
    k = r.vicinity_size
    assert out.listener_vicinity.shape == out.source_vicinity.shape == (k,)
    # The vicinity sets are the k audio points nearest listener and source (world metric = normalised metric).
    d = np.linalg.norm(r.points - np.array([1.0, 1.0, 1.6]), axis=1)
    assert set(out.listener_vicinity) == set(np.argsort(d)[:k])


def test_render_matches_masks_and_the_source_override(ckpt_path):
    r = SceneRenderer.load(ckpt_path)
    mono = np.random.default_rng(0).standard_normal(3000)
    out = r.render((1.0, 1.0, 1.6), 0.0, mono)
    m = r.masks((1.0, 1.0, 1.6), 0.0)
    assert np.allclose(out.mixture, m.mixture) and np.allclose(out.difference, m.difference)
    # Source at +y of a listener facing +x: on the left.
    assert r.masks((1.0, 1.0, 1.6), 0.0, source=(1.0, 3.0, 1.6)).theta == pytest.approx(90.0)
    assert r.masks((1.0, 1.0, 1.6), 0.0, source=(1.0, -3.0, 1.6)).theta == pytest.approx(-90.0)
    moved = r.render((1.0, 1.0, 1.6), 0.0, mono, source=(1.0, 3.0, 1.6))
    assert not np.allclose(moved.mixture, out.mixture)  # C_S re-computed for the new source
    again = r.render((1.0, 1.0, 1.6), 0.0, mono)  # back to the trained source
    assert np.allclose(again.binaural, out.binaural, atol=1e-6)


def test_render_can_return_the_predicted_magnitudes(ckpt_path):
    """``magnitudes=True`` gives the ear magnitudes of the tail model that the waveform was made from."""
    from avgs import dsp
    from avgs.acoustics.reverb_tail import decay_per_frame
    from avgs.acoustics.synthesis import Masks, ear_magnitudes

    r = SceneRenderer.load(ckpt_path)
    mono = np.random.default_rng(1).standard_normal(3000).astype(np.float32)
    assert r.render((1.0, 1.0, 1.6), 20.0, mono).magnitudes is None  # only when asked for
    out = r.render((1.0, 1.0, 1.6), 20.0, mono, magnitudes=True)
    assert out.magnitudes.shape == (2, 257, 1 + 3000 // 128) and out.reverb is not None
    mag = dsp.magnitude(mono)[None]  # [1, F, N]
    decay = decay_per_frame(torch.from_numpy(r.rt60), 128 / 22050)
    masks = Masks(torch.from_numpy(out.mixture)[None], torch.from_numpy(out.difference)[None],
                  torch.from_numpy(out.reverb)[None], decay)
    _, s_l, s_r = ear_magnitudes(mag, masks)  # the tail's power computed from the same source
    np.testing.assert_allclose(out.magnitudes, torch.cat([s_l, s_r]).numpy(), rtol=1e-4, atol=1e-6)
    # the waveform is their iSTFT with the source phase: its own magnitudes are close, not equal
    resynth = dsp.magnitude(out.binaural).numpy()
    rel = np.linalg.norm(resynth - out.magnitudes) / np.linalg.norm(out.magnitudes)
    assert 0 < rel < 0.5


def test_bad_inputs_raise_value_error(ckpt_path):
    r = SceneRenderer.load(ckpt_path)
    ok = np.zeros(100)
    for kwargs in (
        dict(listener=(0, 0, np.nan), yaw=0.0, mono=ok),
        dict(listener=(0, 0), yaw=0.0, mono=ok),
        dict(listener=(0, 0, 0), yaw=np.inf, mono=ok),
        dict(listener=(0, 0, 0), yaw=0.0, mono=np.array([0.0, np.nan])),
        dict(listener=(0, 0, 0), yaw=0.0, mono=np.zeros(0)),
        dict(listener=(0, 0, 0), yaw=0.0, mono=ok, source=(np.inf, 0, 0)),
    ):
        with pytest.raises(ValueError):
            r.render(**kwargs)


def test_render_from_a_worker_thread(ckpt_path):
    r = SceneRenderer.load(ckpt_path)
    mono = np.random.default_rng(1).standard_normal(2000)
    ref = r.render((2.0, 1.0, 1.6), 45.0, mono).binaural
    results = []
    worker = threading.Thread(target=lambda: results.extend(r.render((2.0, 1.0, 1.6), 45.0, mono).binaural for _ in range(5)))
    worker.start()
    while worker.is_alive():
        assert r.points.shape == (400, 3)  # reading the immutable arrays meanwhile
    worker.join()
    assert len(results) == 5 and all(np.array_equal(b, ref) for b in results)


def test_atomic_writes_leave_nothing_half_written_and_get_normal_permissions(tmp_path):
    import os
    import stat

    from avgs.io.atomic import atomic_path, write_text

    path = write_text(tmp_path / "a.txt", "hello")
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~mask  # not mkstemp's 0600
    with pytest.raises(RuntimeError):
        with atomic_path(tmp_path / "a.txt") as tmp:
            tmp.write_text("half")
            raise RuntimeError("writer failed")
    assert path.read_text() == "hello" and sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]

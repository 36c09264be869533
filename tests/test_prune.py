"""Pruning to the points some vicinity can use: same output everywhere in the region."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from avgs.render.prune import (
    cell_centres,
    checkpoint_bytes,
    current_k,
    needed_points,
    prune_checkpoint,
    subsample_checkpoint,
)
from avgs.io.checkpoint import load_checkpoint, save_checkpoint, untrained_checkpoint
from avgs.cli import main as cli_main
from avgs.data.frame import SceneFrame
from avgs.render.renderer import SceneRenderer

ROOM = np.array([[0.0, 0.0, 0.0], [6.0, 4.0, 3.0]])
SOURCE = np.array([4.5, 2.5, 1.2])
WALKABLE = np.array([[1.0, 1.0, 1.5], [3.0, 3.0, 1.7]])


@pytest.fixture(scope="module")
def ckpt():
    rng = np.random.default_rng(0)
    pts = rng.uniform(ROOM[0], ROOM[1], size=(3000, 3))
    g = {"means": torch.zeros(50, 3), "sh": torch.zeros(50, 16, 3)}
    return untrained_checkpoint(pts, SOURCE, frame=SceneFrame(ROOM.mean(0), 1 / 3), seed=1, gaussians=g)


def test_cell_centres_cover_the_box():
    centres, delta = cell_centres([0, 0, 1], [1, 2, 1], 0.5)
    assert centres.shape == (2 * 4 * 1, 3) and delta == pytest.approx(0.5 * np.sqrt(0.5**2 + 0.5**2))
    with pytest.raises(ValueError, match="max >= min"):
        cell_centres([1, 0, 0], [0, 1, 1], 0.5)


def test_needed_points_hold_every_vicinity_in_the_region():
    g = torch.Generator().manual_seed(0)
    X = torch.rand(2000, 3, generator=g).numpy()
    k = 100
    keep = set(needed_points(X, k, [0.2, 0.2, 0.5], [0.5, 0.6, 0.5], cell=0.05).tolist())
    assert len(keep) < len(X)
    q = np.random.default_rng(1).uniform([0.2, 0.2, 0.5], [0.5, 0.6, 0.5], size=(200, 3))
    d = ((X[None] - q[:, None]) ** 2).sum(-1)
    for row in np.argsort(d, axis=1)[:, :k]:
        assert set(row.tolist()) <= keep


def test_pruned_checkpoint_renders_the_same_inside_the_region(ckpt, tmp_path):
    full = SceneRenderer(ckpt)
    pruned_ckpt, info = prune_checkpoint(ckpt, WALKABLE)
    assert info["points_after"] < info["points_before"] == 3000
    assert pruned_ckpt["vicinity_k"] == full.vicinity_size == 450  # k fixed, not 15 % of the new N
    assert "gaussians" not in pruned_ckpt and checkpoint_bytes(pruned_ckpt) < checkpoint_bytes(ckpt)
    path = save_checkpoint(pruned_ckpt, tmp_path / "pruned.ckpt")
    pruned = SceneRenderer.load(path)
    assert pruned.vicinity_size == full.vicinity_size
    rng = np.random.default_rng(2)
    mono = rng.standard_normal(4000).astype(np.float32)
    for _ in range(12):
        lis = rng.uniform(WALKABLE[0], WALKABLE[1])
        yaw = float(rng.uniform(-180, 180))
        a, b = full.render(lis, yaw, mono), pruned.render(lis, yaw, mono)
        assert np.allclose(a.mixture, b.mixture, atol=1e-5) and np.allclose(a.difference, b.difference, atol=1e-5)
        # the phase iterations carry the masks' float rounding into the waveform a little further
        assert np.allclose(a.binaural, b.binaural, atol=1e-4 * float(np.abs(a.binaural).max()))
        # the same points, named by position
        pa = {tuple(p) for p in full.points[a.listener_vicinity].round(5)}
        pb = {tuple(p) for p in pruned.points[b.listener_vicinity].round(5)}
        assert pa == pb
    sa = {tuple(p) for p in full.points[full.masks(WALKABLE[0], 0).source_vicinity].round(5)}
    sb = {tuple(p) for p in pruned.points[pruned.masks(WALKABLE[0], 0).source_vicinity].round(5)}
    assert sa == sb


def test_subsampled_budget_puts_k_back_at_the_percentile(ckpt):
    small = subsample_checkpoint(prune_checkpoint(ckpt, WALKABLE)[0], 500)
    assert small["audio_points"]["X"].shape == (500, 3) and current_k(small) == 75
    with pytest.raises(ValueError, match="point budget"):
        subsample_checkpoint(ckpt, 0)


def test_prune_command(ckpt, tmp_path, capsys):
    src = save_checkpoint(ckpt, tmp_path / "in.ckpt")
    out = tmp_path / "out.ckpt"
    region = [str(v) for v in WALKABLE.reshape(-1)]
    assert cli_main(["prune", str(src), "--out", str(out), "--region", *region, "--keep-gaussians"]) == 0
    text = capsys.readouterr().out
    assert "audio points kept" in text and "k = 450 fixed" in text
    pruned = load_checkpoint(out)
    assert "gaussians" in pruned and pruned["vicinity_k"] == 450

"""Camera views for stage 1 (``avgs.data.views``): poses, intrinsics in their three forms,
downscaling, and errors that name the file at fault."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from PIL import Image

from avgs.data.views import DEFAULT_FOV_DEG, load_views


def write_views(root, n=3, size=(20, 16), fov=50.0, intrinsics=None, scaled=True, split="train"):
    """A scene folder with ``n`` frames of constant colour k / n (red) and poses at x = k / 4
    (normalised, inside [-1, 1]^3)."""
    W, H = size
    (root / "frames").mkdir(parents=True, exist_ok=True)
    path = []
    for k in range(1, n + 1):
        img = np.zeros((H, W, 3), np.uint8)
        img[..., 0] = round(255 * k / n)
        Image.fromarray(img).save(root / "frames" / f"{k:05d}.png")
        c2w = np.eye(4)
        c2w[0, 3] = k / 4
        entry = {"camera_to_world": c2w.reshape(-1).tolist(), "file_path": f"frames/{k:05d}.png"}
        if fov is not None:
            entry["fov"], entry["aspect"] = fov, W / H
        path.append(entry)
    name = f"transforms_scale_{split}.json" if scaled else f"transforms_{split}.json"
    (root / name).write_text(json.dumps({"camera_path": path}))
    if intrinsics is not None:
        (root / "transforms.json").write_text(json.dumps({**intrinsics, "frames": []}))
    return root


def test_poses_images_and_fov_intrinsics(tmp_path):
    views = load_views(write_views(tmp_path), "train")
    assert len(views) == 3 and views.images.shape == (3, 16, 20, 3) and views.images.dtype == torch.float32
    assert torch.allclose(views.images[1, 0, 0], torch.tensor([2 / 3, 0.0, 0.0]), atol=1 / 255)
    assert views.c2w.shape == (3, 4, 4) and views.camera_centers()[:, 0].tolist() == [0.25, 0.5, 0.75]
    f = 0.5 * 16 / math.tan(math.radians(50.0) / 2)  # vertical field of view, square pixels
    assert torch.allclose(views.K[0], torch.tensor([[f, 0, 10.0], [0, f, 8.0], [0, 0, 1]]), atol=1e-4)
    assert views.frame_numbers == [1, 2, 3] and views.paths[0].name == "00001.png"
    assert views.scene_extent() == pytest.approx(1.1 * 0.25)


def test_transforms_json_intrinsics_win_and_follow_the_image_size(tmp_path):
    K = {"fl_x": 30.0, "fl_y": 32.0, "cx": 19.0, "cy": 15.0, "w": 40, "h": 32}  # stated for 40x32 frames
    views = load_views(write_views(tmp_path, intrinsics=K), "train")  # the frames are 20x16
    assert torch.allclose(views.K[2], torch.tensor([[15.0, 0, 9.5], [0, 16.0, 7.5], [0, 0, 1]]))


def test_no_intrinsics_falls_back_to_the_default_fov_with_a_warning(tmp_path):
    with pytest.warns(UserWarning, match=f"{DEFAULT_FOV_DEG} degrees"):
        views = load_views(write_views(tmp_path, fov=None), "train")
    f = 0.5 * 16 / math.tan(math.radians(DEFAULT_FOV_DEG) / 2)
    assert float(views.K[0, 1, 1]) == pytest.approx(f)


def test_downscale_averages_pixels_and_scales_k(tmp_path):
    full = load_views(write_views(tmp_path, size=(20, 16)), "train")
    half = load_views(tmp_path, "train", downscale=2)
    assert half.images.shape == (3, 8, 10, 3)
    assert torch.allclose(half.images.mean(dim=(1, 2)), full.images.mean(dim=(1, 2)), atol=1e-6)
    assert torch.allclose(half.K[:, :2], full.K[:, :2] / 2)
    again = full.downscaled(2)
    assert torch.allclose(again.images, half.images) and torch.allclose(again.K, half.K)
    sub = full.subset([2, 0])
    assert sub.frame_numbers == [3, 1] and torch.equal(sub.images[1], full.images[0])


def test_unscaled_poses_go_through_scene_json(tmp_path):
    write_views(tmp_path, scaled=False)
    (tmp_path / "scene.json").write_text(json.dumps({"to_normalised": {"center": [0.5, 0.0, 0.0], "scale": 2.0}}))
    views = load_views(tmp_path, "train")
    assert views.camera_centers()[:, 0].tolist() == [-0.5, 0.0, 0.5]


def test_errors_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="transforms_scale_val.json"):
        load_views(write_views(tmp_path), "val")
    (tmp_path / "frames" / "00002.png").unlink()
    with pytest.raises(FileNotFoundError, match="00002.png"):
        load_views(tmp_path, "train")
    (tmp_path / "frames" / "00002.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match="00002.png.*not a readable image"):
        load_views(tmp_path, "train")
    Image.fromarray(np.zeros((10, 10, 3), np.uint8)).save(tmp_path / "frames" / "00002.png")
    with pytest.raises(ValueError, match="00002.png: image is 10x10"):
        load_views(tmp_path, "train")
    (tmp_path / "transforms_scale_train.json").write_text("{bad json")
    with pytest.raises(ValueError, match="transforms_scale_train.json: not valid JSON"):
        load_views(tmp_path, "train")
    with pytest.raises(ValueError, match="split must be"):
        load_views(tmp_path, "test")
    write_views(tmp_path / "b", intrinsics={"fl_x": 30.0})
    with pytest.raises(ValueError, match="transforms.json: has some but not all"):
        load_views(tmp_path / "b", "train")

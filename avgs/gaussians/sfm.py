"""Sparse 3D points from a scene's key frames and their known camera poses (structure from
motion with the cameras fixed), through COLMAP's Python bindings (``pycolmap``).

3D-GS, and the AV-GS paper after it, start G from SfM points. A real recording has no
scene geometry, only frames and poses, so the points are triangulated here:

1. the train views (:func:`avgs.data.views.load_views`) are written as PNGs into a
   temporary folder, with a COLMAP database beside them (removed at the end: nothing is
   written into the scene folder);
2. SIFT features are extracted with each view's own pinhole intrinsics;
3. each view is matched with its :data:`PAIRS_PER_VIEW` nearest views that look the same
   way (the poses choose the pairs; no exhaustive matching), and the matches are
   geometrically verified;
4. ``pycolmap.triangulate_points`` triangulates tracks with the poses held fixed;
   points seen in fewer than three views, or with a mean reprojection error above
   :data:`MAX_REPROJECTION_PX`, are dropped. Colours are the mean of the observing pixels.

Points come out in the frame of the poses (the normalised frame, as the model computes).
Camera conventions: our poses are OpenGL camera-to-world; COLMAP wants OpenCV
world-to-camera (``cam_from_world``), as :func:`avgs.gaussians.cameras.viewmat_from_c2w`
gives; both put pixel centres at +0.5.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from avgs.data.views import Views, load_views
from avgs.gaussians.cameras import viewmat_from_c2w

PAIRS_PER_VIEW = 20
"Each view is matched with this many of its nearest views (by pose) that look the same way."
MAX_VIEW_ANGLE_DEG = 75.0
"Views whose optical axes differ by more than this are never paired."
MAX_REPROJECTION_PX = 2.0
"Triangulated points with a larger mean reprojection error (pixels) are dropped."
SIFT_PEAK_THRESHOLD = 0.002
"""SIFT's contrast threshold (COLMAP's default 0.0067 finds few corners on plain walls with faint
texture, such as our generated scenes' tiles)."""
MIN_TRACK_LENGTH = 3
"Points seen in fewer views than this are dropped."
MIN_POINTS = 100
"Fewer triangulated points than this is an error (too little to start G from)."


@dataclass(frozen=True, eq=False)
class SparsePoints:
    """Triangulated points of one scene (the frame of its poses)."""

    points: np.ndarray  # [n, 3] float32
    colors: np.ndarray  # [n, 3] float32 RGB in [0, 1]
    stats: dict = field(default_factory=dict)  # views, features, pairs, verified pairs, track length, error, seconds


def image_pairs(c2w: np.ndarray, per_view: int = PAIRS_PER_VIEW, max_angle_deg: float = MAX_VIEW_ANGLE_DEG) -> list[tuple[int, int]]:
    """Pairs ``(i, j)``, ``i < j``, of views to match: for every view, its ``per_view`` nearest
    views whose optical axes lie within ``max_angle_deg`` of its own.

    Nearness is the distance between camera centres plus the distance between the points
    one scene-radius ahead of each camera, so that views of the same surface pair up
    even from a little apart. ``c2w [V, 4, 4]`` OpenGL camera-to-world.
    """
    c2w = np.asarray(c2w, dtype=np.float64)
    centers = c2w[:, :3, 3]  # [V, 3]
    axes = -c2w[:, :3, 2]  # [V, 3] viewing directions (OpenGL looks along -Z)
    axes = axes / np.maximum(np.linalg.norm(axes, axis=1, keepdims=True), 1e-12)
    radius = max(float(np.linalg.norm(centers - centers.mean(0), axis=1).max()), 1e-3)
    ahead = centers + radius * axes  # [V, 3]
    dist = np.linalg.norm(centers[:, None] - centers[None], axis=-1) + np.linalg.norm(ahead[:, None] - ahead[None], axis=-1)
    facing = axes @ axes.T >= np.cos(np.radians(max_angle_deg))  # [V, V]
    dist[~facing] = np.inf
    np.fill_diagonal(dist, np.inf)
    pairs = set()
    for i in range(len(c2w)):
        for j in np.argsort(dist[i])[:per_view]:
            if np.isfinite(dist[i, j]):
                pairs.add((min(i, int(j)), max(i, int(j))))
    return sorted(pairs)


def triangulate_views(
    views: Views, *, name: str = "scene", threads: int | None = None, seed: int = 0, progress: bool = True
) -> SparsePoints:
    """Sparse points ``[n, 3]`` (frame of ``views.c2w``) with colours from posed RGB views.

    ``seed`` fixes COLMAP's RANSAC and triangulation sampling (the same views give the same
    points). Raises ValueError naming ``name`` when fewer than :data:`MIN_POINTS` triangulate.
    """
    import pycolmap
    from tqdm.auto import tqdm

    t0 = time.perf_counter()
    threads = int(threads or torch.get_num_threads())
    V, H, W = len(views), views.height, views.width
    if V < 3:
        raise ValueError(f"{name}: SfM points need at least 3 posed views, got {V}")
    c2w = views.c2w.detach().cpu().double().numpy()  # [V, 4, 4]
    pairs = image_pairs(c2w)
    bar = tqdm(total=3, desc=f"SfM points ({name})", disable=not progress, dynamic_ncols=True)
    level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = pycolmap.logging.ERROR  # COLMAP's per-image log lines
    try:
        with tempfile.TemporaryDirectory(prefix="avgs-sfm-") as tmp:
            tmp = Path(tmp)
            bar.set_postfix_str("features")
            known, features = _extract(pycolmap, tmp, views, threads)
            bar.update(1)
            bar.set_postfix_str(f"matching {len(pairs)} pairs")
            verified = _match(pycolmap, tmp, pairs, threads, seed)
            bar.update(1)
            bar.set_postfix_str(f"triangulating ({verified} verified pairs)")
            points, colors, tracks, errors = _triangulate(pycolmap, tmp, known, threads, seed)
            bar.update(1)
    finally:
        pycolmap.logging.minloglevel = level
        bar.close()
    keep = (tracks >= MIN_TRACK_LENGTH) & (errors <= MAX_REPROJECTION_PX) & np.all(np.isfinite(points), axis=1)
    points, colors, tracks, errors = points[keep], colors[keep], tracks[keep], errors[keep]
    stats = {
        "views": V,
        "width": W,
        "height": H,
        "features": int(features),
        "pairs": len(pairs),
        "verified_pairs": int(verified),
        "points": int(len(points)),
        "mean_track_length": float(tracks.mean()) if len(tracks) else 0.0,
        "mean_reprojection_px": float(errors.mean()) if len(errors) else 0.0,
        "seconds": time.perf_counter() - t0,
    }
    if len(points) < MIN_POINTS:
        raise ValueError(
            f"{name}: only {len(points)} SfM points triangulated from {V} views of {W}x{H} pixels ({features} features, "
            f"{verified} of {len(pairs)} view pairs verified); at least {MIN_POINTS} are needed to start G. "
            "More, larger or more textured overlapping frames would give more; --init gs starts from random points"
        )
    return SparsePoints(points.astype(np.float32), colors.astype(np.float32), stats)


def sfm_points(
    scene_dir: str | Path, split: str = "train", *, threads: int | None = None, seed: int = 0, progress: bool = True
) -> SparsePoints:
    """:func:`triangulate_views` of a scene folder's ``split`` views (frames and poses only)."""
    scene_dir = Path(scene_dir)
    views = load_views(scene_dir, split)
    return triangulate_views(views, name=str(scene_dir), threads=threads, seed=seed, progress=progress)


def _extract(pycolmap, tmp: Path, views: Views, threads: int):
    """Write the views as ``tmp/images/NNNNN.png``, extract SIFT features into ``tmp/database.db``
    with each view's own pinhole camera; returns (the reconstruction of the known cameras and
    poses, ids as in the database; the number of features)."""
    from PIL import Image

    images_dir = tmp / "images"
    images_dir.mkdir()
    rgb = (views.images.detach().cpu().clamp(0, 1) * 255).round().to(torch.uint8).numpy()  # [V, H, W, 3]
    names = [f"{i:05d}.png" for i in range(len(views))]
    for n, img in zip(names, rgb):
        Image.fromarray(img).save(images_dir / n)
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = threads
    extraction.sift.peak_threshold = SIFT_PEAK_THRESHOLD
    pycolmap.extract_features(
        tmp / "database.db", images_dir, image_names=names, camera_mode=pycolmap.CameraMode.PER_IMAGE,
        reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu,
    )  # fmt: skip
    K = views.K.detach().cpu().double().numpy()  # [V, 3, 3]
    cam_from_world = viewmat_from_c2w(views.c2w.detach().cpu().double()).numpy()  # [V, 4, 4] OpenCV world-to-camera
    known = pycolmap.Reconstruction()
    with pycolmap.Database.open(tmp / "database.db") as db:
        features = 0
        for image in db.read_all_images():
            i = int(Path(image.name).stem)
            k = K[i]
            camera = pycolmap.Camera(
                camera_id=image.camera_id, model="PINHOLE", width=views.width, height=views.height,
                params=[k[0, 0], k[1, 1], k[0, 2], k[1, 2]],
            )  # fmt: skip
            db.update_camera(camera)  # the extraction guessed the intrinsics; matches are verified with these
            known.add_camera_with_trivial_rig(camera)
            pose = pycolmap.Rigid3d(cam_from_world[i, :3, :4])
            known.add_image_with_trivial_frame(pycolmap.Image(name=image.name, camera_id=image.camera_id, image_id=image.image_id), pose)
            features += db.num_keypoints_for_image(image.image_id)
    return known, features


def _match(pycolmap, tmp: Path, pairs: list[tuple[int, int]], threads: int, seed: int) -> int:
    """Match and verify the given view pairs in ``tmp/database.db``; returns the verified pairs."""
    pairs_path = tmp / "pairs.txt"
    pairs_path.write_text("".join(f"{i:05d}.png {j:05d}.png\n" for i, j in pairs))
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = threads
    pairing = pycolmap.ImportedPairingOptions()
    pairing.match_list_path = pairs_path
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = seed
    pycolmap.match_image_pairs(
        tmp / "database.db", matching_options=matching, pairing_options=pairing, verification_options=verification,
        device=pycolmap.Device.cpu,
    )  # fmt: skip
    with pycolmap.Database.open(tmp / "database.db") as db:
        return int(db.num_verified_image_pairs())


def _triangulate(pycolmap, tmp: Path, known, threads: int, seed: int):
    """Tracks triangulated with the poses fixed: (points [n, 3], colours [n, 3] in [0, 1],
    track lengths [n], mean reprojection errors [n] in pixels)."""
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = threads
    options.random_seed = seed
    options.triangulation.random_seed = seed
    options.triangulation.ignore_two_view_tracks = MIN_TRACK_LENGTH >= 3
    out_dir = tmp / "sparse"
    out_dir.mkdir()
    rec = pycolmap.triangulate_points(known, tmp / "database.db", tmp / "images", out_dir, clear_points=True, options=options)
    pts = list(rec.points3D.values())
    if not pts:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=int), np.zeros(0)
    xyz = np.array([p.xyz for p in pts], dtype=np.float64)
    rgb = np.array([p.color for p in pts], dtype=np.float64) / 255.0
    tracks = np.array([p.track.length() for p in pts], dtype=int)
    errors = np.array([p.error for p in pts], dtype=np.float64)
    return xyz, rgb, tracks, errors

"""Triangulate a scene's SfM points here (pycolmap) for a device run: ``avgs_gpu.py`` reads
them through ``AVGS_SFM_POINTS``.

    .venv/bin/python scripts/device/sfm_points.py data/stripped/demo_house .gpu/sfm_demo_house.npz
"""
import sys
from pathlib import Path

import numpy as np

from avgs.io.atomic import atomic_path
from avgs.gaussians.sfm import sfm_points

scene, out = Path(sys.argv[1]), Path(sys.argv[2])
sparse = sfm_points(scene, "train")
with atomic_path(out) as tmp:
    with open(tmp, "wb") as f:
        np.savez(f, points=sparse.points, colors=sparse.colors, views=sparse.stats.get("views", 0))
print(f"{len(sparse.points)} points from {scene} -> {out}: {sparse.stats}")

"""`avgs` on the device: the CLI as is; without matplotlib there, the curves PNG is skipped.

``AVGS_SFM_POINTS=FILE.npz`` (``points`` [n, 3], ``colors`` [n, 3]): ``--init sfm`` starts
from these points instead of triangulating, for a machine without pycolmap (a 38 MB wheel).
Write the file where pycolmap is, from the same frames (the triangulation is seeded, so
the points are those the run would make): ``scripts/device/sfm_points.py SCENE OUT.npz``.
"""
import os
import sys

import numpy as np

import avgs.train.pipeline as pipeline
from avgs.cli import main

try:
    import matplotlib  # noqa: F401
except ImportError:
    pipeline.plot_curves = lambda *a, **k: None

if os.environ.get("AVGS_SFM_POINTS"):
    import avgs.gaussians.sfm as sfm

    stored = np.load(os.environ["AVGS_SFM_POINTS"])

    def stored_points(scene_dir, split="train", **_):
        return sfm.SparsePoints(stored["points"].astype(np.float32), stored["colors"].astype(np.float32),
                                {"views": int(stored["views"]), "stored": os.environ["AVGS_SFM_POINTS"]})

    sfm.sfm_points = stored_points
sys.exit(main())
